"""A participant at the web study's page in a real browser (tests/study/test_web_browser.py):
what the page shows now, read from its DOM, and real key presses and clicks answering it.

The page (study/web/static/experiment.js) is jsPsych: each screen is a new element under
``#jspsych-content`` (or, for a message shown outside jsPsych, ``.tf-page``); a screen is
answered once, and the next one is waited for by the answered element going stale (jsPsych
empties the display when a screen ends). Every wait is bounded: a page that stops moving fails
the test with what it shows instead of hanging it.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

from selenium.common.exceptions import TimeoutException
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.support import expected_conditions as EC
from selenium.webdriver.support.ui import WebDriverWait

STEP_S = 90.0  # at most this long for the page's next screen (loading, a trial's playback)
PAGE_STEPS = 600  # screens of one page load, at most (a whole session has ~150)
RETRY_KEY_S = 2.0  # the audio check takes its key only once its sentence ended: press again

# The screen on show, as {"kind", "el" (its element), "text", "key" | "src" | "code"}; null while
# nothing is to be answered (loading, fixation cross, stimulus, inter-trial blank, a post).
DETECT = r"""
const content = document.querySelector('#jspsych-content');
const el = (content && content.firstElementChild) || document.querySelector('.tf-page');
if (!el) return null;
const scope = content || document.body;
const text = (scope.innerText || '').trim();
const out = {el: el, text: text};
if (scope.querySelector('#jspsych-loading-progress-bar-container')) return null;  // preload
if (!content && text.startsWith('Loading the study')) return null;  // index.html, until main
const err = scope.querySelector('.tf-error');
if (err) return Object.assign(out, {kind: 'error', text: err.innerText.trim()});
const code = scope.querySelector('.tf-code');
if (code || text.indexOf(arguments[0]) >= 0)
  return Object.assign(out, {kind: 'end', code: code ? code.innerText.trim() : null});
const agree = [...scope.querySelectorAll('button')].find(b => b.innerText.trim() === 'I agree');
if (agree) return Object.assign(out, {kind: 'consent', el: agree, screen: el});
const fs = scope.querySelector('#jspsych-fullscreen-btn');
if (fs) return Object.assign(out, {kind: 'fullscreen', el: fs, screen: el});
if (text.startsWith('Keyboard check'))
  return Object.assign(out, {kind: 'key', key: scope.querySelector('kbd').innerText.trim()});
const q = scope.querySelector('.tf-question');
if (q && q.innerText.trim() === 'Which word did you hear?') {
  const keys = {};
  for (const k of scope.querySelectorAll('.tf-key'))
    keys[k.innerText.replace(k.querySelector('kbd').innerText, '').trim()] =
      k.querySelector('kbd').innerText.trim();
  return Object.assign(out, {kind: 'audio-check', keys: keys});
}
if (q) {
  const img = scope.querySelector('img.tf-face');
  const speaker = scope.querySelector('svg.tf-speaker');
  if (img || speaker)
    return Object.assign(out, {kind: 'response', src: img ? img.getAttribute('src') : null});
}
if (scope.querySelector('.tf-text')) return Object.assign(out, {kind: 'text'});
return null;
"""

# a video stimulus playing (started, not ended) on screen now
VIDEO_PLAYING = r"""
const v = document.querySelector('#jspsych-video-keyboard-response-stimulus');
return Boolean(v && v.currentTime > 0 && !v.ended);
"""


def text_names(site: dict) -> dict:
    """The page's text screens by the first line they show: ``welcome``, ``practice``,
    ``practice_over``, ``part:<block>-<period>``, ``sound-check``, ``sound-again``."""
    first = {"welcome": site["texts"]["welcome"], "practice": site["texts"]["practice"],
             "practice_over": site["texts"]["practice_over"],
             **{f"part:{k}": v for k, v in site["texts"]["blocks"].items()},
             "sound-check": "Sound check:", "sound-again": "That was not the word."}
    return {name: t.strip().splitlines()[0][:30] for name, t in first.items()}


@dataclass
class Participant:
    """A participant at the page: answers every screen as asked, and each study trial with
    ``rule(trial)`` (a response name), the trial being ``plan[next]`` (the lab's trial order
    of this participant, :func:`study.design.session_trials`; ``plan`` may be a function
    giving it, called at the first study trial, once the server has made the session)."""

    driver: object
    site: dict
    plan: list
    rule: object
    next: int = 0  # the trial index the next study response screen asks
    screens: list = field(default_factory=list)  # (kind, name or detail) of every screen
    shown: list = field(default_factory=list)  # (trial_index, what the response screen showed)
    in_practice: bool = False

    def detect(self):
        return self.driver.execute_script(DETECT, self.site["texts"]["end"])

    def name_of(self, text: str) -> str:
        for name, first in text_names(self.site).items():
            if text.startswith(first):
                return name
        return f"text?{text[:60]!r}"

    def press(self, key: str) -> None:
        ActionChains(self.driver).send_keys(key).perform()

    def wait_gone(self, el, what: str, timeout: float = STEP_S) -> bool:
        try:
            WebDriverWait(self.driver, timeout, poll_frequency=0.05).until(
                EC.staleness_of(el))
            return True
        except TimeoutException:
            if timeout < STEP_S:
                return False
            raise AssertionError(f"the page stayed on {what} for {timeout:g} s after it was "
                                 "answered") from None

    def run(self, *, until_answered: int | None = None, until_playing: int | None = None):
        """Answer screens until the end screen (returned), or return None right after the
        key of trial ``until_answered - 1`` was pressed, or once the video of trial
        ``until_playing`` plays (nothing answered for it)."""
        for _ in range(PAGE_STEPS):
            def ready(d):
                if until_playing is not None and self.next == until_playing and \
                        d.execute_script(VIDEO_PLAYING):
                    return {"kind": "playing"}
                return self.detect()
            try:
                s = WebDriverWait(self.driver, STEP_S, poll_frequency=0.05).until(ready)
            except TimeoutException:
                body = self.driver.execute_script("return document.body.innerText")[:400]
                raise AssertionError(f"no screen to answer for {STEP_S:g} s after "
                                     f"{self.screens[-3:]}; the page shows: {body!r}") from None
            kind = s["kind"]
            if kind == "playing":
                self.screens.append(("playing", self.next))
                return None
            if kind in ("end", "error"):
                self.screens.append((kind, s["text"]))
                return s
            if kind in ("consent", "fullscreen"):
                self.screens.append((kind, None))
                s["el"].click()
                self.wait_gone(s["screen"], kind)
            elif kind == "key":
                self.screens.append((kind, s["key"]))
                self.press(s["key"].lower())
                self.wait_gone(s["el"], f"the key check of {s['key']}")
            elif kind == "audio-check":
                check = self.site["audio_check"]
                key = s["keys"][check["answer"]]
                self.screens.append((kind, key))
                deadline = time.monotonic() + STEP_S
                while True:  # its key counts only once the sentence was played
                    self.press(key)
                    if self.wait_gone(s["el"], kind, RETRY_KEY_S):
                        break
                    assert time.monotonic() < deadline, "the audio check never took its key"
            elif kind == "text":
                name = self.name_of(s["text"])
                self.screens.append((kind, name))
                if name == "practice":
                    self.in_practice = True
                elif name == "practice_over":
                    self.in_practice = False
                self.press(" ")
                self.wait_gone(s["el"], f"the text {name}")
            elif kind == "response":
                if self.in_practice:
                    self.screens.append(("practice-response", s["src"]))
                    self.press(self.site["keys"]["not_sure"])
                    self.wait_gone(s["el"], "the practice's response screen")
                    continue
                if callable(self.plan):  # made by the server once the page opened it
                    self.plan = self.plan()
                trial = self.plan[self.next]
                self.shown.append((trial.trial_index, s["src"]))
                self.screens.append(("response", trial.trial_index))
                self.press(self.site["keys"][self.rule(trial)])
                self.next += 1
                if until_answered is not None and self.next == until_answered:
                    return None
                self.wait_gone(s["el"], f"the response screen of trial {trial.trial_index}")
        raise AssertionError(f"the page showed over {PAGE_STEPS} screens: {self.screens[-5:]}")


def shown_stimulus(site: dict, trial) -> str | None:
    """What the response screen of ``trial`` must show: its video's last frame (the ``src``
    of the face image), or None for the speaker symbol of an audio-only trial."""
    entry = site["stimuli"][trial.stimulus_id]
    return entry.get("last_frame") if entry["kind"] == "video" else None
