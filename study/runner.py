"""One participant's session of the perception study (paper §VII-C), run in PsychoPy.

:func:`run_session` first checks everything that can be refused, and only then writes anything:
:func:`study.session.check_session` (participant id, options, stimuli and their checksums,
allocation list, data file: a complete session is never reopened, an interrupted one only with
``resume``; another session running, free disk space), then the display (:func:`check_display`)
and the audio backend, which need PsychoPy. A refused session takes no allocation slot and
leaves no lock file or folder. Then :func:`study.session.open_session` locks, claims the slot
and opens the data file, and the plan is executed in a window: instructions; one practice
trial, not written (skipped on resume; the neutral sentence's audio-only track, so neither face
is seen before its block); then each block after a short instruction. A trial is a fixation
cross, the stimulus, and the response screen (the face's last frame, or a speaker symbol, above
the four keys and their labels) until a response key; the response time runs from that
screen's onset.

Video frames are decoded, and their ImageStims built, before the trial; the frame drawn is
chosen from the time elapsed since the onset flip, and the sentence's audio is scheduled on
that flip (``Sound.play(when=win)``). Every judgment is appended and fsync'ed to the data file
(``study.data.SessionFile``) and saved by PsychoPy's ExperimentHandler in ``sub-<id>/psychopy/``.
Escape, at any moment, ends the session: what was written stays, the trial in progress is not
written, the slot stays with the participant, and ``--resume`` continues in the same order.

A ``responder`` (tests, demonstrations, simulated observers) answers through PsychoPy's keyboard
device: its key is injected on the response screen, the path a person's key press takes. It may
answer ``"escape"`` to press Escape.
"""
from __future__ import annotations

import csv
import json
import math
import os
import platform
import sys
import time
import wave
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from PIL import Image

from groundwork.errors import ParameterError
from study import data as sdata
from study.design import RESPONSES, required_stimuli
from study.session import PRACTICE, SessionPlan, check_session, open_session
from study.stimuli import read_video_frames

LABELS = {"neutral": "Neutral", "happy": "Happy", "sad": "Sad", "not_sure": "Not sure"}
DEFAULT_RT_S = 0.8
LATE_FACTOR = 1.5  # a frame interval longer than this × the nominal refresh is late
WELCOME = ("In this study you will see and hear a person saying short sentences.\n\n"
           "After each one, tell us which emotion the person showed:\n\n{prompt}\n\n"
           "Answer with your first impression. There are no right or wrong answers.")
BLOCK_TEXT = {("visual", 0): "Part 1 of 4: faces without sound.\n\nWatch the face.",
              ("audio", 0): "Part 2 of 4: voices without a face.\n\nListen to the voice.",
              ("bimodal", 1): "Part 3 of 4: a talking face with sound.\n\nWatch and listen.",
              ("bimodal", 2): "Part 4 of 4: another talking face with sound.\n\nWatch and "
                              "listen."}
QUESTION = "Which emotion did the person show?"
PRACTICE_TEXT = "First, one practice trial with a voice only."
PRACTICE_OVER = "The practice is over. The study begins now."
END_TEXT = "Thank you! The session is over."
CONTINUE = "\n\nPress SPACE to continue."


class _Abort(Exception):
    """Escape was pressed."""


def scripted_responder(path):
    """``f(trial) -> (response, rt_s)`` from a CSV with columns ``stimulus_id,response[,rt_s]``
    (``rt_s`` defaults to 0.8 s). Every stimulus of the design must be answered, once."""
    path = Path(path)
    if not path.is_file():
        raise ParameterError(f"response script {path} not found (a CSV with columns "
                             "stimulus_id,response[,rt_s])")
    with open(path, newline="", encoding="utf-8-sig") as f:  # as saved by Excel, too
        reader = csv.DictReader(f)
        missing = [c for c in ("stimulus_id", "response") if c not in (reader.fieldnames or [])]
        if missing:
            raise ParameterError(f"{path}: missing columns {missing}; expected "
                                 "stimulus_id,response[,rt_s]")
        rows = list(reader)
    known, table = required_stimuli(), {}
    for line, r in enumerate(rows, start=2):
        where = f"{path}, row {line}"
        sid, resp = (r["stimulus_id"] or "").strip(), (r["response"] or "").strip()
        if sid not in known:
            raise ParameterError(f"{where}: stimulus_id {sid!r} is not a stimulus of the "
                                 f"design; allowed: {', '.join(known)}")
        if sid in table:
            raise ParameterError(f"{where}: stimulus_id {sid!r} is listed twice")
        if resp not in RESPONSES:
            raise ParameterError(f"{where}: response {resp!r}; allowed: {', '.join(RESPONSES)}")
        raw = (r.get("rt_s") or "").strip()
        try:
            rt = float(raw) if raw else DEFAULT_RT_S
        except ValueError:
            rt = float("nan")
        if not (math.isfinite(rt) and 0 < rt <= 60):
            raise ParameterError(f"{where}: rt_s {raw!r}; allowed: a number of seconds in "
                                 "(0, 60], or blank for 0.8")
        table[sid] = (resp, rt)
    absent = [s for s in known if s not in table]
    if absent:
        raise ParameterError(f"{path}: no response for stimuli {absent}; every stimulus of the "
                             "design needs one row")
    return lambda trial: table[trial.stimulus_id]


def _silent_sound(path):
    """Stands in for ``psychopy.sound.Sound`` when the audio backend is ``none``."""
    with wave.open(str(path), "rb") as w:
        duration = w.getnframes() / float(w.getframerate())
    return SimpleNamespace(getDuration=lambda: duration, play=lambda **_: None,
                           stop=lambda **_: None)


def check_display() -> None:
    """Refuse, in one line, a session that cannot open its window: on Linux, PsychoPy's
    windows (pyglet) need an X display. Connects to it once (pyglet keeps the connection for
    the window)."""
    if not sys.platform.startswith("linux"):
        return  # Windows and macOS: the desktop is always there
    name = os.environ.get("DISPLAY", "")
    hint = ("run the session from the lab computer's desktop, or headless under "
            "xvfb-run -a -s '-screen 0 1024x768x24' talkingface study run ...")
    if not name:
        raise ParameterError(f"no display: DISPLAY is not set, so no window can open; {hint}")
    import pyglet
    from pyglet.canvas.xlib import NoSuchDisplayException

    try:
        pyglet.canvas.get_display()
    except NoSuchDisplayException:
        raise ParameterError(f"no display: cannot connect to the X display DISPLAY={name!r}; "
                             f"{hint}") from None


def _psychopy(audio_backend, probe_wav):
    """Import PsychoPy (audio library chosen first) and check the backend can play a file."""
    import psychopy
    from psychopy import prefs

    if audio_backend != "none":
        prefs.hardware["audioLib"] = [audio_backend]  # in memory only: never saved
    from psychopy import data, logging, visual
    from psychopy.hardware import keyboard

    if not keyboard.havePTB:  # the "event" fallback drops key names in this PsychoPy version
        raise ParameterError("PsychoPy's psychtoolbox keyboard is not available; install the "
                             "psychtoolbox package (pip) and libjack-jackd2-0 (Debian)")

    psy = SimpleNamespace(version=psychopy.__version__, data=data, logging=logging,
                          visual=visual, keyboard=keyboard, Sound=_silent_sound, speaker="")
    if audio_backend != "none":
        from psychopy import sound

        try:
            probe = sound.Sound(str(probe_wav))
        except Exception as exc:  # no device, no library: refuse before any window opens
            reason = " ".join(str(exc).split()).rstrip(".")  # one line
            raise ParameterError(
                f"audio backend {audio_backend!r} cannot play {probe_wav}: {reason}. Check the "
                "sound device, or choose another: --set study.audio_backend=sounddevice|ptb"
            ) from exc
        psy.speaker = str(getattr(probe.speaker, "name", probe.speaker))
        psy.Sound = lambda p: sound.Sound(str(p), speaker=probe.speaker)  # the same device
    return psy


class _Screen:
    """The window, keyboard and drawing of one session."""

    def __init__(self, psy, *, size, fullscreen, keys, responder):
        v = psy.visual
        self.psy, self.responder = psy, responder
        self.win = v.Window(size=tuple(int(s) for s in size), fullscr=fullscreen, units="pix",
                            color=(0, 0, 0), colorSpace="rgb", allowGUI=False)
        self.win.mouseVisible = False
        self.t0 = psy.logging.defaultClock.getTime()
        self.period = getattr(self.win, "monitorFramePeriod", None) or 1 / 60
        self.kb = psy.keyboard.Keyboard()
        self.keys = dict(zip(RESPONSES, keys))
        self.response_of = {k: r for r, k in self.keys.items()}
        w, h = self.win.size
        self.W, self.H = float(w), float(h)
        text = dict(color="white", height=max(18, self.H / 32), wrapWidth=self.W * 0.8)
        self.prompt = v.TextStim(self.win, text="   ".join(
            f"{self.keys[r].upper()} = {LABELS[r]}" for r in RESPONSES),
            pos=(0, -0.4 * self.H), **text)
        self.question = v.TextStim(self.win, text=QUESTION, pos=(0, -0.31 * self.H), **text)
        self.message = v.TextStim(self.win, text="", **text)
        self.cross = v.ShapeStim(self.win, vertices="cross", size=40, fillColor="white",
                                 lineColor="white", pos=(0, 0.08 * self.H))  # the face's centre
        body = [(-85, -25), (-50, -25), (-10, -65), (-10, 65), (-50, 25), (-85, 25)]
        arcs = [[(5 + r * math.cos(a), r * math.sin(a)) for a in np.linspace(-0.8, 0.8, 12)]
                for r in (35, 60, 85)]
        shapes = [v.ShapeStim(self.win, vertices=body, fillColor="white", lineColor="white",
                              pos=(0, 0.08 * self.H))] + \
            [v.ShapeStim(self.win, vertices=a, closeShape=False, lineWidth=5, fillColor=None,
                         lineColor="white", pos=(0, 0.08 * self.H)) for a in arcs]
        self.speaker = lambda: [s.draw() for s in shapes]  # the audio-only trials' screen

    # --- keyboard -------------------------------------------------------------------------
    def _keys(self, names):  # keys still down, then keys pressed and released
        got = self.kb.getKeys(keyList=names, waitRelease=False) + \
            self.kb.getKeys(keyList=names, waitRelease=True)
        return sorted(got, key=lambda k: k.tDown)

    def check_escape(self):
        if self._keys(["escape"]):
            raise _Abort

    def inject(self, key, rt_s):
        """A key press as the keyboard device reports it (tests and simulated observers)."""
        kp = self.kb.device.makeResponse(code=key, tDown=self.psy.logging.defaultClock.getTime()
                                         + rt_s, name=key)
        kp.rt, kp.duration = rt_s, 0.1

    def wait_key(self, draw, names, *, inject=None, capture=False):
        """Show ``draw`` from the next flip until one of ``names`` (or Escape) is pressed;
        ``inject`` ``(key, rt_s)`` presses a key right after that flip; ``capture`` grabs the
        screen for :meth:`Window.saveMovieFrames`."""
        draw()
        if capture:
            self.win.getMovieFrame(buffer="back")
        self.win.callOnFlip(self.kb.clearEvents)
        self.win.callOnFlip(self.kb.clock.reset)  # rt from this screen's onset
        if inject is not None:
            self.win.callOnFlip(self.inject, *inject)
        self.win.flip()
        while not (got := self._keys([*names, "escape"])):
            draw()
            self.win.flip()
        if got[0].name == "escape":
            raise _Abort
        return got[0]

    # --- screens --------------------------------------------------------------------------
    def hold(self, draw, seconds):
        """Show ``draw`` for ``seconds`` (timed from its onset flip), watching for Escape."""
        if seconds <= 0:
            return
        draw()
        t_on = self.win.flip()
        while self.win.getFutureFlipTime(clock=None) - t_on < seconds:
            self.check_escape()
            draw()
            self.win.flip()

    def text(self, message, *, wait=True, seconds=0.0):
        """A message until SPACE is pressed (or for ``seconds`` if not ``wait``)."""
        self.message.text = message
        if not wait:
            return self.hold(self.message.draw, seconds)
        self.wait_key(self.message.draw, ["space"],
                      inject=("space", 0.2) if self.responder is not None else None)

    def frames(self, video):
        """Decode every frame and build its ImageStim, scaled to fit above the prompt."""
        frames, fps = read_video_frames(video)
        fh, fw = frames.shape[1:3]
        scale = min(1.0, 0.8 * self.W / fw, 0.62 * self.H / fh)
        stims = [self.psy.visual.ImageStim(self.win, image=Image.fromarray(f),
                                           size=(fw * scale, fh * scale),
                                           pos=(0, 0.08 * self.H)) for f in frames]
        return stims, fps

    def present(self, images, fps, snd):
        """The stimulus from its onset flip to the end of the video and of the sound."""
        duration = max(len(images) / fps if images else 0.0, snd.getDuration() if snd else 0.0)
        (images[0].draw if images else self.speaker)()
        if snd is not None:
            snd.play(when=self.win)  # starts on the onset flip
        flips = [self.win.flip()]
        while (t := self.win.getFutureFlipTime(clock=None) - flips[0]) < duration:
            self.check_escape()
            if images:
                images[min(int(t * fps), len(images) - 1)].draw()
            else:
                self.speaker()
            flips.append(self.win.flip())
        iv = np.diff(flips)
        return {"n_frames": len(flips), "frames_late": int(np.sum(iv > LATE_FACTOR * self.period)),
                "frame_interval_ms_mean": 1000 * iv.mean() if len(iv) else None,
                "frame_interval_ms_max": 1000 * iv.max() if len(iv) else None,
                "audio_onset_s": flips[0] - self.t0 if snd is not None else None}

    def trial(self, trial, stim, *, fixation_s, iti_s, screenshot=None, practice=False):
        """Fixation, stimulus, response; returns (response, key, rt_s, qc). A responder is
        not asked about the practice trial (it answers "not sure"), so it sees exactly the
        session's trials, in order."""
        images, fps = self.frames(stim.video) if trial.face != "none" else ([], 30.0)
        snd = self.psy.Sound(stim.wav) if trial.audio != "none" else None
        self.hold(self.cross.draw, fixation_s)
        try:
            qc = self.present(images, fps, snd)
        finally:  # at its end, or on Escape
            if snd is not None:
                snd.stop()

        def draw():
            (images[-1].draw if images else self.speaker)()
            self.question.draw()
            self.prompt.draw()

        inject = None
        if self.responder is not None:
            response, rt = ("not_sure", DEFAULT_RT_S) if practice else \
                _checked(trial, *self.responder(trial))
            inject = ("escape" if response == "escape" else self.keys[response], rt)
        kp = self.wait_key(draw, list(self.response_of), inject=inject,
                           capture=screenshot is not None)
        if screenshot is not None:  # the response screen as the participant saw it
            Path(screenshot).parent.mkdir(parents=True, exist_ok=True)
            self.win.saveMovieFrames(str(screenshot))
        self.psy.logging.exp(f"trial {trial.trial_index} {trial.stimulus_id}: key {kp.name}, "
                             f"rt {kp.rt}")
        self.hold(lambda: None, iti_s)
        return self.response_of[kp.name], kp.name, float(kp.rt), qc


def _checked(trial, response, rt):
    """A responder's answer, checked."""
    rt = float(rt) if isinstance(rt, (int, float, np.number)) else float("nan")
    if response not in (*RESPONSES, "escape") or not (math.isfinite(rt) and rt >= 0):
        raise ParameterError(f"the responder answered {response!r} in {rt!r} s to "
                             f"{trial.stimulus_id}; allowed: {', '.join(RESPONSES)} (or "
                             "escape) and a time in seconds >= 0")
    return response, rt


def _quietly(psy, fn):
    """``fn()`` with PsychoPy's "will be overwritten" warnings of the per-trial saves going to
    the session's log file only, not the console."""
    psy.logging.flush()  # earlier messages as usual
    level, psy.logging.console.level = psy.logging.console.level, psy.logging.ERROR
    try:
        return fn()
    finally:
        psy.logging.flush()
        psy.logging.console.level = level


def _judgments(screen: _Screen, plan: SessionPlan, psy, exp) -> None:
    """The welcome, the practice trial, then the plan's steps, each judgment written as it is
    made (the data file, fsync'ed; PsychoPy's files)."""
    opts = dict(fixation_s=plan.fixation_s, iti_s=plan.iti_s)
    screen.text(WELCOME.format(prompt=screen.prompt.text) + CONTINUE)
    if plan.practice:
        screen.text(PRACTICE_TEXT + CONTINUE)
        screen.trial(PRACTICE, plan.stimuli[PRACTICE.stimulus_id], practice=True, **opts)
        screen.text(PRACTICE_OVER + CONTINUE)
    for step in plan.steps:
        if step.part is not None:
            screen.text(BLOCK_TEXT[step.part] + CONTINUE)
        response, key, rt, qc = screen.trial(
            step.trial, step.stimulus, screenshot=plan.screenshot if step.screenshot else None,
            **opts)
        row = sdata.trial_row(step.trial, participant_id=plan.participant_id,
                              sequence=plan.sequence, response=response, response_key=key,
                              rt_s=rt, simulated=plan.simulated,
                              responder_model=plan.responder_model, session=plan.session,
                              site="lab", qc=qc)
        plan.file.append(row)
        for c in sdata.COLUMNS:
            exp.addData(c, row[c])
        exp.nextEntry()
        names = _quietly(psy, exp.save)  # per trial: PsychoPy's record survives a crash
        exp.queueNextCollision("overwrite", fileName=names)


def _execute(plan: SessionPlan, psy, responder) -> str:
    """Run the plan in a window, keeping the sidecar and PsychoPy's files; returns the end
    state (``complete``, ``aborted``, or ``error: …`` as the exception is raised on)."""
    versions = {"python": platform.python_version(), "psychopy": psy.version,
                "numpy": np.__version__}
    sdata.write_dataset_description(plan.study_dir, name="talkingface emotion-perception study",
                                    simulated=plan.simulated)
    base = plan.psychopy_base(time.strftime("%Y%m%dT%H%M%S"))
    this = plan.record(start=sdata.now_iso(), versions=versions, audio_device=psy.speaker)
    meta = plan.metadata(versions, this)

    def save_sidecar():
        sdata.write_atomic(plan.sidecar_path, json.dumps(meta, indent=1) + "\n")

    base.parent.mkdir(parents=True, exist_ok=True)
    exp = psy.data.ExperimentHandler(
        name=f"talkingface-{sdata.TASK}",  # the rows carry session, sequence, ...
        extraInfo={"participant": plan.participant_id, "study_seed": plan.study_seed},
        originPath=__file__, savePickle=True, saveWideText=True, dataFileName=str(base))
    log = psy.logging.LogFile(exp.dataFileName + ".log", level=psy.logging.EXP, filemode="w")
    this["psychopy_files"] = [exp.dataFileName + e for e in (".csv", ".psydat", ".log")]
    save_sidecar()
    end_state, screen = "error", None
    try:
        screen = _Screen(psy, size=plan.window_size, fullscreen=plan.fullscreen,
                         keys=[plan.keys[r] for r in RESPONSES], responder=responder)
        this["frame_period_s"] = screen.period
        _judgments(screen, plan, psy, exp)
        end_state = "complete"
        screen.text(END_TEXT, wait=False,
                    seconds=1.0 if responder is None else 0.1)
    except _Abort:  # Escape (on the closing screen of a complete session, too late to abort)
        end_state = "complete" if plan.file.complete else "aborted"
    except BaseException as exc:
        end_state = f"error: {type(exc).__name__}: {exc}"
        raise
    finally:
        _quietly(psy, exp.close)  # saves what was completed; no further saves at exit
        if screen is not None:
            screen.win.close()
        psy.logging.flush()
        psy.logging.root.removeTarget(log)
        this.update(end=sdata.now_iso(), end_state=end_state, rows_at_end=len(plan.file.done))
        save_sidecar()
        if end_state == "complete":  # otherwise the slot stays "assigned", for --resume
            sdata.Allocation(plan.study_dir).set_status(plan.participant_id, "complete")
    return end_state


def run_session(study_dir, stimuli_dir, participant_id: str, *, study_seed: int,
                n_slots: int = 20, resume: bool = False, fullscreen: bool = False,
                keys=("n", "h", "s", "u"), practice: bool = True, fixation_s: float = 0.5,
                iti_s: float = 0.5, audio_backend: str = "sounddevice", responder=None,
                responder_model: str = "human", screenshot=None,
                window_size=(1024, 768)) -> dict:
    """One session of ``participant_id`` (see the module text).

    Returns ``{"participant_id", "sequence", "rows", "complete", "aborted", "data",
    "session", "sidecar"}``: the number of judgments in the data file, whether all 27 are
    there, whether Escape ended the session, the data file's path, this session's number and
    the sidecar's path. Refusals raise ParameterError before anything is written
    (:func:`study.session.check_session`, the display, the audio backend).
    """
    check = check_session(study_dir, stimuli_dir, participant_id, study_seed=study_seed,
                          n_slots=n_slots, resume=resume, fullscreen=fullscreen, keys=keys,
                          practice=practice, fixation_s=fixation_s, iti_s=iti_s,
                          audio_backend=audio_backend, responder_model=responder_model,
                          screenshot=screenshot, window_size=window_size)
    check_display()
    psy = _psychopy(audio_backend, check.probe_wav)
    plan = open_session(check)
    try:  # the participant's session lock is held until the session ends
        end_state = _execute(plan, psy, responder)
    finally:
        plan.release()
    return plan.result(end_state)
