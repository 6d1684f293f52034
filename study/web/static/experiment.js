/* The perception study (paper §VII-C) as a web page: jsPsych 8 (issue 41).
 *
 * The same texts, keys and trial as the lab's PsychoPy runner (study/runner.py): a trial is a
 * fixation cross, the stimulus (a talking face with its sentence, one muxed MP4; the face alone,
 * silent; or the voice alone, with the cross on screen), then the response screen (the face's
 * last frame, or a speaker symbol, above the question and the four keys) until a key; the
 * response time runs from that screen's onset. Each judgment is posted to the server as soon as
 * it is made, and the next trial waits for the reply (web_contract.md).
 *
 * In a browser the jsPsych plugins are the globals their dist/index.browser.min.js define; the
 * bootstrap (main) fetches study.json, opens the session (POST api/session) and runs the
 * timeline, or jsPsych.simulate when the URL asks for it and the server sent answers. In Node,
 * module.exports gives buildTimeline and its helpers (the plugins must be set as globals under
 * the same names first: tests/study/simulate_web.cjs).
 */
(function (root) {
  "use strict";

  const PLUGINS = {
    preload: "jsPsychPreload", button: "jsPsychHtmlButtonResponse",
    browserCheck: "jsPsychBrowserCheck", fullscreen: "jsPsychFullscreen",
    html: "jsPsychHtmlKeyboardResponse", audio: "jsPsychAudioKeyboardResponse",
    video: "jsPsychVideoKeyboardResponse", call: "jsPsychCallFunction",
  };
  const SPACE = [" "];
  const now = () => root.performance.now();

  function plugins() {
    const out = {};
    for (const [key, name] of Object.entries(PLUGINS)) {
      if (!root[name]) throw new Error(`the jsPsych plugin ${name} is not loaded`);
      out[key] = root[name];
    }
    return out;
  }

  // --- HTML --------------------------------------------------------------------------------
  function esc(text) {
    const map = { "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" };
    return String(text).replace(/[&<>"']/g, (c) => map[c]);
  }

  /** Plain text with blank-line paragraphs (the lab's texts) as HTML. */
  function paragraphs(text) {
    return String(text).split(/\n\s*\n/).map((p) => p.trim()).filter(Boolean)
      .map((p) => `<p>${esc(p).replace(/\n/g, "<br>")}</p>`).join("");
  }

  function keysHtml(study) {
    return '<div class="tf-keys">' + Object.keys(study.keys).map((r) =>
      `<span class="tf-key"><kbd>${esc(study.keys[r].toUpperCase())}</kbd> ` +
      `${esc(study.labels[r])}</span>`).join("") + "</div>";
  }

  function textHtml(text, study, withContinue = true) {
    const parts = String(text).split("{prompt}");
    const body = parts.map(paragraphs).join(keysHtml(study));
    return `<div class="tf-text">${body}${withContinue ? paragraphs(study.texts.continue) : ""}</div>`;
  }

  /** The speaker symbol of the audio-only response screen (the runner's shapes). */
  function speakerSvg() {
    const body = "-85,-25 -50,-25 -10,-65 -10,65 -50,25 -85,25";
    const arcs = [35, 60, 85].map((r) => {
      const [x0, y0, x1, y1] = [5 + r * Math.cos(-0.8), r * Math.sin(-0.8),
        5 + r * Math.cos(0.8), r * Math.sin(0.8)].map((v) => v.toFixed(2));
      return `<path d="M ${x0} ${y0} A ${r} ${r} 0 0 1 ${x1} ${y1}"/>`;
    }).join("");
    return '<svg class="tf-speaker" viewBox="-100 -100 200 200" role="img" aria-label="sound">' +
      `<polygon points="${body}" fill="white"/><g fill="none" stroke="white" ` +
      `stroke-width="8" stroke-linecap="round">${arcs}</g></svg>`;
  }

  const stage = (inner, below = "") =>
    `<div class="tf-stage">${inner}</div><div class="tf-below">${below}</div>`;
  const cross = () => '<div class="tf-cross">+</div>';
  const errorHtml = (message) =>
    `<div class="tf-text tf-error">${paragraphs(message)}</div>`;

  // --- what a plan needs ---------------------------------------------------------------------
  function stimulusFiles(study, trial) {
    const s = study.stimuli[trial.stimulus_id];
    if (!s) throw new Error(`study.json has no stimulus ${trial.stimulus_id}`);
    if (s.kind === "audio") return { kind: "audio", media: s.audio };
    return { kind: "video", media: trial.block === "visual" ? s.silent : s.bimodal,
      image: s.last_frame };
  }

  /** Every file the plan's trials, the practice and the audio check play or show. */
  function planFiles(study, plan) {
    const trials = [...plan.trials];
    if (plan.practice) trials.push({ stimulus_id: study.practice_trial.stimulus_id, block: "audio" });
    trials.push({ stimulus_id: study.audio_check.stimulus_id, block: "audio" });
    const out = { video: new Set(), images: new Set(), audio: new Set() };
    for (const t of trials) {
      const f = stimulusFiles(study, t);
      if (f.kind === "audio") out.audio.add(f.media);
      else { out.video.add(f.media); out.images.add(f.image); }
    }
    return { video: [...out.video], images: [...out.images], audio: [...out.audio] };
  }

  // --- the timeline ----------------------------------------------------------------------------
  function fullscreenNow() {
    const d = root.document;
    return Boolean(d && (d.fullscreenElement || d.webkitFullscreenElement));
  }
  function focusNow() {
    const d = root.document;
    return d && typeof d.hasFocus === "function" ? d.hasFocus() : true;
  }

  /** Fixation, stimulus, response (and, unless practice, the post and the ITI) of one trial. */
  function trialNodes(ctx, trial, { practice }) {
    const { jsPsych, study, plan, P } = ctx;
    const f = stimulusFiles(study, trial);
    const rec = {};
    const tag = (part) => ({ tf: practice ? `practice-${part}` : part,
      study_trial: trial.trial_index, stimulus_id: trial.stimulus_id });
    const nodes = [];
    if (!practice && trial.opens_part) {
      nodes.push({ type: P.html, stimulus: textHtml(study.texts.blocks[trial.opens_part], study),
        choices: SPACE, data: { tf: "part", part: trial.opens_part } });
    }
    nodes.push({
      type: P.html, stimulus: stage(cross()), choices: "NO_KEYS",
      trial_duration: Math.round(1000 * study.fixation_s), data: tag("fixation"),
      on_start: () => {
        rec.events = jsPsych.data.getInteractionData().count();
        rec.fullscreen = fullscreenNow();
        rec.focused = focusNow();
      },
    });
    const stimulusEnd = () => {
      rec.stimulus_end_ms = rec.stimulus_end_ms ?? now();
      rec.stimulus_onset_ms = rec.stimulus_onset_ms ?? rec.stimulus_load_ms;
    };
    if (f.kind === "video") {
      nodes.push({
        type: P.video, stimulus: [f.media], choices: "NO_KEYS", autoplay: true,
        width: null, height: null, // sized by style.css
        trial_ends_after_video: true, prompt: '<div class="tf-below"></div>',
        css_classes: ["tf-video"], data: tag("stimulus"),
        on_load: () => {
          rec.stimulus_load_ms = now();
          const v = jsPsych.getDisplayElement()
            .querySelector("#jspsych-video-keyboard-response-stimulus");
          if (!v) return; // simulated: nothing on screen
          v.addEventListener("playing", () => { rec.stimulus_onset_ms ??= now(); });
          v.addEventListener("ended", () => { rec.stimulus_end_ms ??= now(); });
        },
        on_finish: stimulusEnd,
      });
    } else {
      nodes.push({
        type: P.audio, stimulus: f.media, choices: "NO_KEYS", trial_ends_after_audio: true,
        prompt: stage(cross()), data: tag("stimulus"),
        on_load: () => { rec.stimulus_load_ms = now(); }, // the plugin plays right after it
        on_finish: stimulusEnd,
      });
    }
    const picture = f.kind === "video" ? `<img class="tf-face" src="${esc(f.image)}" alt="">`
      : speakerSvg();
    nodes.push({
      type: P.html, choices: Object.values(study.keys), data: tag("response"),
      stimulus: stage(picture, `<p class="tf-question">${esc(study.texts.question)}</p>` +
        keysHtml(study)),
      simulation_options: practice ? "practice" : `response:${trial.trial_index}`,
      on_load: () => { rec.response_onset_ms = now(); },
      on_finish: (data) => {
        rec.response_ms = now();
        rec.key = data.response;
        rec.rt = data.rt;
      },
    });
    if (!practice) nodes.push(postNode(ctx, trial, rec));
    nodes.push({ type: P.html, stimulus: "", choices: "NO_KEYS",
      trial_duration: Math.round(1000 * study.iti_s), data: tag("iti") });
    return nodes;
  }

  /** The judgment as the contract's POST /api/trial body. */
  function trialBody(ctx, trial, rec) {
    const events = ctx.jsPsych.data.getInteractionData().values().slice(rec.events ?? 0);
    const has = (name) => events.some((e) => e.event === name);
    return {
      participant_id: ctx.plan.participant_id, token: ctx.plan.token,
      trial_index: trial.trial_index, stimulus_id: trial.stimulus_id,
      response_key: rec.key, rt_ms: rec.rt,
      browser: {
        stimulus_onset_ms: rec.stimulus_onset_ms ?? null,
        stimulus_end_ms: rec.stimulus_end_ms ?? null,
        response_onset_ms: rec.response_onset_ms ?? null, response_ms: rec.response_ms ?? null,
        refresh_hz: ctx.refresh_hz ?? null,
        fullscreen: Boolean(rec.fullscreen) && !has("fullscreenexit") && fullscreenNow(),
        focused: Boolean(rec.focused) && !has("blur") && focusNow(),
        browser: ctx.browser ?? null,
        user_agent: root.navigator ? root.navigator.userAgent : null,
      },
    };
  }

  function postNode(ctx, trial, rec) {
    return {
      type: ctx.P.call, async: true,
      data: { tf: "post", study_trial: trial.trial_index, stimulus_id: trial.stimulus_id },
      func: (done) => {
        ctx.io.postTrial(trialBody(ctx, trial, rec)).then((reply) => {
          ctx.last = reply;
          done({ saved: reply ? reply.saved : null, complete: Boolean(reply && reply.complete) });
        }, (err) => {
          ctx.jsPsych.abortExperiment(errorHtml(`${err.message}\n\nThe study cannot go on; ` +
            "please contact the researcher."));
        });
      },
    };
  }

  function checksNodes(ctx) {
    const { jsPsych, study, P } = ctx;
    const nodes = [{
      type: P.browserCheck,
      features: ["browser", "browser_version", "mobile", "os", "width", "height", "webaudio",
        "fullscreen", "vsync_rate"],
      inclusion_function: (d) => !d.mobile,
      exclusion_message: () => errorHtml("This study needs a computer with a keyboard; it " +
        "cannot run on a phone or a tablet. Thank you for your interest."),
      data: { tf: "browser" },
      on_finish: (d) => {
        ctx.browser = `${d.browser} ${d.browser_version}`;
        ctx.refresh_hz = typeof d.vsync_rate === "number" ? d.vsync_rate : null;
      },
    }, {
      type: P.fullscreen, fullscreen_mode: true, data: { tf: "fullscreen" },
      message: '<div class="tf-text">' + paragraphs("The study runs in full screen.") + "</div>",
      button_label: "Continue in full screen",
    }];
    for (const r of Object.keys(study.keys)) {
      nodes.push({ type: P.html, choices: [study.keys[r]], data: { tf: "key-check", key: r },
        stimulus: '<div class="tf-text"><p>Keyboard check: press the key ' +
          `<kbd>${esc(study.keys[r].toUpperCase())}</kbd> (${esc(study.labels[r])}).</p></div>` });
    }
    const check = study.audio_check;
    const choiceKeys = check.choices.map((_, i) => String(i + 1));
    const choiceHtml = '<div class="tf-keys">' + check.choices.map((c, i) =>
      `<span class="tf-key"><kbd>${i + 1}</kbd> ${esc(c)}</span>`).join("") + "</div>";
    let heard = null;
    const wrong = () => heard !== choiceKeys[check.choices.indexOf(check.answer)];
    nodes.push({
      timeline: [
        { type: P.html, choices: SPACE, data: { tf: "audio-check-intro" },
          stimulus: textHtml("Sound check: please turn your sound on. You will hear a short " +
            "sentence; then press the key of the word it ends with.", study) },
        { type: P.audio, stimulus: study.stimuli[check.stimulus_id].audio, choices: choiceKeys,
          response_allowed_while_playing: false, simulation_options: "audio_check",
          prompt: stage(cross(), '<p class="tf-question">Which word did you hear?</p>' +
            choiceHtml),
          data: { tf: "audio-check" }, on_finish: (d) => { heard = d.response; } },
        { timeline: [{ type: P.html, choices: SPACE, data: { tf: "audio-check-again" },
          stimulus: textHtml("That was not the word. Please check your sound and listen " +
            "again.", study) }], conditional_function: wrong },
      ],
      loop_function: wrong,
    });
    return nodes;
  }

  function completionHtml(study, completion) {
    let html = paragraphs(study.texts.end);
    if (completion && completion.code) {
      html += `<p>Your completion code is <strong class="tf-code">${esc(completion.code)}` +
        "</strong>.</p>";
    }
    if (completion && completion.url) {
      html += `<p>You will now be taken back to the study's site; if nothing happens, ` +
        `<a href="${esc(completion.url)}">follow this link</a>.</p>`;
    } else {
      html += "<p>You may close this window now.</p>";
    }
    return `<div class="tf-text">${html}</div>`;
  }

  /** The consent page; declining ends the experiment there (nothing posted). */
  function consentNodes(jsPsych, study) {
    const P = plugins();
    let declined = false;
    return [{
      type: P.button, choices: ["I agree", "I do not agree"], simulation_options: "consent",
      stimulus: `<div class="tf-text">${paragraphs(study.consent)}</div>`,
      data: { tf: "consent" }, on_finish: (d) => { declined = d.response !== 0; },
    }, {
      timeline: [{ type: P.call, data: { tf: "declined" }, func: () => jsPsych.abortExperiment(
        '<div class="tf-text">' + paragraphs("You chose not to take part. Thank you for your " +
          "time; you may close this window now.") + "</div>") }],
      conditional_function: () => declined,
    }];
  }

  /**
   * The timeline of one participant's session.
   *
   * study: study.json; plan: the POST api/session reply (its trials still to run, in order);
   * io: {postTrial(body) -> Promise<reply>, redirect(url)?, fetchCompletion()?}.
   */
  function buildTimeline(jsPsych, study, plan, io, { consent = true } = {}) {
    const P = plugins();
    const ctx = { jsPsych, study, plan, io, P, last: null, browser: null, refresh_hz: null };
    const files = planFiles(study, plan);
    const timeline = [{
      type: P.preload, video: files.video, images: files.images, audio: files.audio,
      show_progress_bar: true, continue_after_error: false, max_load_time: 600000,
      message: '<div class="tf-text"><p>Loading the study\'s videos and sounds…</p></div>',
      error_message: errorHtml("The study's videos and sounds could not be loaded. Please " +
        "check your connection and reload the page."),
      data: { tf: "preload" },
    }];
    if (consent) timeline.push(...consentNodes(jsPsych, study));
    timeline.push(...checksNodes(ctx));
    timeline.push({ type: P.html, choices: SPACE, data: { tf: "welcome" },
      stimulus: textHtml(study.texts.welcome, study) });
    if (plan.practice) {
      const pt = { trial_index: -1, block: "audio", stimulus_id: study.practice_trial.stimulus_id };
      timeline.push({ type: P.html, choices: SPACE, data: { tf: "practice-intro" },
        stimulus: textHtml(study.texts.practice, study) });
      timeline.push(...trialNodes(ctx, pt, { practice: true }));
      timeline.push({ type: P.html, choices: SPACE, data: { tf: "practice-over" },
        stimulus: textHtml(study.texts.practice_over, study) });
    }
    for (const trial of plan.trials) timeline.push(...trialNodes(ctx, trial, { practice: false }));
    timeline.push({
      type: P.call, async: true, data: { tf: "completion" },
      func: (done) => {
        const have = ctx.last && ctx.last.completion;
        if (have || !io.fetchCompletion) { done(null); return; }
        io.fetchCompletion().then((c) => { ctx.last = { ...ctx.last, completion: c }; done(null); },
          () => done(null));
      },
    }, {
      type: P.html, choices: "NO_KEYS", data: { tf: "end" },
      stimulus: () => completionHtml(study, ctx.last && ctx.last.completion),
      on_load: () => {
        const c = ctx.last && ctx.last.completion;
        if (c && c.url && io.redirect) io.redirect(c.url);
      },
    });
    return timeline;
  }

  /** jsPsych.simulate's options: each response screen answers with answers[trial_index] (a
   * *-normal video is judged twice, visual-only and bimodal, so the index names the trial). */
  function simulationOptions(study, answers) {
    const check = study.audio_check;
    const out = {
      default: {},
      consent: { data: { response: 0 } },
      practice: { data: { response: study.keys.not_sure, rt: 800 } },
      audio_check: { data: { response: String(check.choices.indexOf(check.answer) + 1),
        rt: 900 } },
    };
    for (const [index, a] of Object.entries(answers || {})) {
      out[`response:${index}`] = { data: { response: a.key, rt: 1000 * a.rt_s } };
    }
    return out;
  }

  // --- the page in a browser ---------------------------------------------------------------------
  const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

  /**
   * POST JSON; returns the reply. With retry, network errors and 5xx are retried with back-off
   * (1 s doubling to 30 s), onWait(message) telling the participant; a 409 "duplicate" counts as
   * saved; any other error rejects with the server's one line.
   */
  async function postJSON(url, body, { retry = false, onWait = () => {} } = {}) {
    let wait = 1000;
    for (;;) {
      let res = null;
      let problem = null;
      try {
        res = await fetch(url, { method: "POST", headers: { "Content-Type": "application/json" },
          body: JSON.stringify(body), cache: "no-store" });
      } catch (err) {
        problem = `the server cannot be reached (${err.message})`;
      }
      if (res) {
        let reply = null;
        try { reply = await res.json(); } catch (err) { reply = null; }
        if (res.ok) return reply;
        if (res.status === 409 && reply && reply.code === "duplicate") {
          return { saved: body.trial_index, duplicate: true, complete: false, completion: null,
            ...reply };
        }
        const line = (reply && reply.error) || `the server answered ${res.status}`;
        if (res.status < 500 || !retry) throw new Error(line);
        problem = line;
      }
      if (!retry) throw new Error(problem);
      onWait(`Saving your answer: ${problem}. Trying again in ${Math.round(wait / 1000)} s…`);
      await sleep(wait);
      wait = Math.min(2 * wait, 30000);
    }
  }

  function measureRefresh(frames = 30, timeoutMs = 2000) {
    return new Promise((resolve) => {
      if (!root.requestAnimationFrame) { resolve(null); return; }
      const times = [];
      const timer = setTimeout(() => resolve(null), timeoutMs); // a hidden tab draws nothing
      const step = (t) => {
        times.push(t);
        if (times.length <= frames) { root.requestAnimationFrame(step); return; }
        clearTimeout(timer);
        const iv = times.slice(1).map((x, i) => x - times[i]).sort((a, b) => a - b);
        const mid = iv[Math.floor(iv.length / 2)];
        resolve(mid > 0 ? Math.round(10000 / mid) / 10 : null);
      };
      root.requestAnimationFrame(step);
    });
  }

  function showMessage(html) {
    root.document.body.innerHTML = `<div class="tf-page">${html}</div>`;
  }

  async function main() {
    const study = await (await fetch("study.json", { cache: "no-store" })).json();
    const params = Object.fromEntries(new URLSearchParams(root.location.search));
    // what this browser keeps of a participant's session, by the id in the link (one browser may
    // run several participants: each continues their own session, each gives consent)
    const linkId = params.PROLIFIC_PID || params.participant || "";
    const storeKey = `talkingface:${study.title}:${linkId || "(no id in the link)"}`;
    let kept = {};
    try { kept = JSON.parse(root.localStorage.getItem(storeKey) || "{}"); } catch (err) { kept = {}; }
    const mode = params.simulate;
    const simulating = mode === "data-only" || mode === "visual";
    if (!kept.token) { // a new participant: consent first, so one who declines takes no slot
      const first = root.jsPsychModule.initJsPsych({});
      const nodes = consentNodes(first, study);
      if (simulating) await first.simulate(nodes, mode, simulationOptions(study, {}));
      else await first.run(nodes);
      if (first.data.get().filter({ tf: "declined" }).count() > 0) return;
      root.document.body.innerHTML = "";
    }
    const sessionBody = { params, token: kept.token ?? null,
      participant_id: kept.participant_id ?? null,
      browser: { user_agent: root.navigator.userAgent, refresh_hz: await measureRefresh() } };
    const plan = await postJSON("api/session", sessionBody);
    try { // (a completed session's reply carries no token: the one kept stays)
      if (plan.token) {
        root.localStorage.setItem(storeKey, JSON.stringify({ participant_id: plan.participant_id,
          token: plan.token }));
      }
    } catch (err) { /* private windows: a reload starts afresh */ }
    if (plan.complete) { showMessage(completionHtml(study, plan.completion)); return; }
    root.document.body.innerHTML = ""; // the loading message; jsPsych adds its own display
    const jsPsych = root.jsPsychModule.initJsPsych({});
    const status = (message) => {
      jsPsych.getDisplayElement().innerHTML = `<div class="tf-text"><p>${esc(message)}</p></div>`;
    };
    const io = {
      postTrial: (body) => postJSON("api/trial", body, { retry: true, onWait: status }),
      redirect: (url) => setTimeout(() => root.location.assign(url), 3000),
      fetchCompletion: async () => (await postJSON("api/session", {
        ...sessionBody, token: plan.token, participant_id: plan.participant_id })).completion,
    };
    const timeline = buildTimeline(jsPsych, study, plan, io, { consent: false });
    if (simulating && plan.answers) {
      await jsPsych.simulate(timeline, mode, simulationOptions(study, plan.answers));
    } else {
      await jsPsych.run(timeline);
    }
  }

  const api = { buildTimeline, simulationOptions, planFiles, trialBody, postJSON, paragraphs,
    speakerSvg, completionHtml, PLUGINS };
  if (typeof module !== "undefined" && module.exports) {
    module.exports = api;
  } else {
    root.talkingfaceStudy = api;
    root.addEventListener("DOMContentLoaded", () => {
      main().catch((err) => showMessage(errorHtml(`The study could not start: ${err.message}`)));
    });
  }
})(typeof globalThis !== "undefined" ? globalThis : this);
