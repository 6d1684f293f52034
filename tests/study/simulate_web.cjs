#!/usr/bin/env node
/* A whole web session without a person: jsPsych's data-only simulation of a built study page.
 *
 *   node tests/study/simulate_web.cjs BUILT_DIR INPUT.json
 *
 * INPUT.json: {"plan": <a POST api/session reply>, "answers": {"<trial_index>": {"key", "rt_s"}},
 *              "decline": false (optional: the participant declines consent),
 *              "fail_at": null (optional: a trial_index whose post is refused with 400)}.
 * Loads jsdom, jsPsych's CommonJS build and the plugins from study/web/node_modules (the ones the
 * built vendor/ folder was copied from), evaluates BUILT_DIR/experiment.js, builds the timeline
 * with an io.postTrial that records each body and replies as the server would (200, the 27th
 * complete with a code), runs jsPsych.simulate(timeline, "data-only", ...) and prints
 * {"posted": [bodies], "redirects": [urls], "data": jsPsych.data.get().values(),
 *  "display": the page's last HTML}.
 */
"use strict";
const fs = require("fs");
const path = require("path");

const NODE_MODULES = path.resolve(__dirname, "../../study/web/node_modules");
const need = (name) => require(path.join(NODE_MODULES, name));

const [builtDir, inputPath] = process.argv.slice(2);
if (!builtDir || !inputPath) {
  process.stderr.write("usage: node simulate_web.cjs BUILT_DIR INPUT.json\n");
  process.exit(2);
}
const input = JSON.parse(fs.readFileSync(inputPath, "utf8"));
const study = JSON.parse(fs.readFileSync(path.join(builtDir, "study.json"), "utf8"));

const { JSDOM, ResourceLoader } = need("jsdom");
// browser-check names the browser from the user agent; jsdom's own is not one it knows
const USER_AGENT = "Mozilla/5.0 (X11; Linux x86_64) AppleWebKit/537.36 (KHTML, like Gecko) " +
  "Chrome/126.0.0.0 Safari/537.36 jsdom-simulation";
const dom = new JSDOM("<!doctype html><html><head></head><body></body></html>",
  { url: "http://localhost/", pretendToBeVisual: true,
    resources: new ResourceLoader({ userAgent: USER_AGENT }) });
const win = dom.window;
for (const name of ["window", "document", "navigator", "HTMLElement", "Element", "Node",
  "KeyboardEvent", "MouseEvent", "Event", "CustomEvent", "getComputedStyle",
  "requestAnimationFrame", "cancelAnimationFrame", "screen", "localStorage"]) {
  if (!(name in globalThis) || name === "navigator") {
    Object.defineProperty(globalThis, name, { value: name === "window" ? win : win[name],
      configurable: true, writable: true });
  }
}

const { initJsPsych } = need("jspsych");
const PLUGIN_PACKAGES = {
  jsPsychPreload: "plugin-preload", jsPsychHtmlButtonResponse: "plugin-html-button-response",
  jsPsychBrowserCheck: "plugin-browser-check", jsPsychFullscreen: "plugin-fullscreen",
  jsPsychHtmlKeyboardResponse: "plugin-html-keyboard-response",
  jsPsychAudioKeyboardResponse: "plugin-audio-keyboard-response",
  jsPsychVideoKeyboardResponse: "plugin-video-keyboard-response",
  jsPsychCallFunction: "plugin-call-function",
};
for (const [global, pkg] of Object.entries(PLUGIN_PACKAGES)) {
  const mod = need(`@jspsych/${pkg}`);
  globalThis[global] = mod.default || mod;
}
const experiment = require(path.resolve(builtDir, "experiment.js"));

const plan = input.plan;
const posted = [];
const redirects = [];
const total = 27;
const io = {
  postTrial: async (body) => {
    posted.push(JSON.parse(JSON.stringify(body)));
    if (input.fail_at === body.trial_index) {
      throw new Error(`trial_index ${body.trial_index} refused (a test)`);
    }
    const complete = body.trial_index === total - 1;
    return { saved: body.trial_index, rows: body.trial_index + 1, complete,
      completion: complete ? { code: "C0DE", url: "https://example.org/done?cc=C0DE" } : null };
  },
  redirect: (url) => { redirects.push(url); },
};

async function run() {
  const jsPsych = initJsPsych({ display_element: win.document.body });
  const timeline = experiment.buildTimeline(jsPsych, study, plan, io);
  const options = experiment.simulationOptions(study, input.answers || {});
  if (input.decline) options.consent = { data: { response: 1 } };
  await jsPsych.simulate(timeline, "data-only", options);
  const text = JSON.stringify({ posted, redirects, data: jsPsych.data.get().values(),
    display: win.document.body.innerHTML }) + "\n";
  // exit only once a pipe has taken all of it (more than 64 KB is written in pieces)
  await new Promise((resolve) => process.stdout.write(text, resolve));
}

run().then(() => process.exit(0), (err) => {
  process.stderr.write(`simulate_web: ${err.stack || err}\n`);
  process.exit(1);
});
