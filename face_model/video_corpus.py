"""A corpus from real video: landmarks → the 79 markers, audio, phones (``talkingface corpus
from-video``).

For every clip (any video FFmpeg reads, with its audio):

1. **Landmarks**: MediaPipe Face Mesh in its own environment (:mod:`face_model.landmarks`), 478
   per frame, with the face detector's confidence; the 79 markers are fixed combinations of them
   (:data:`face_model.landmarks.MARKER_LANDMARKS`).
2. **Missed frames**: a frame without a face is filled by linear interpolation in time between
   the nearest frames with one (held at the clip's ends) and marked *interpolated*; a clip is
   refused, with the reason, when more than ``max_missing_fraction`` of its frames or a run
   longer than ``max_gap_s`` have no face.
   **One upright face**: a clip is refused when the face detector counts more than one face in
   more than ``max_multi_face_fraction`` of its frames (the face mesh follows one face, which
   need not be the speaker's: on two GRID clips side by side it followed the left one), or when
   the face's median |roll| over its frames exceeds ``max_roll_deg`` (the mesh fits an upright
   face to an upside-down one, its mouth on the forehead); both are measured by
   :mod:`face_model.landmark_worker` and unknown (not checked) in its older files.
3. **30 fps**: each marker coordinate is interpolated linearly in time from the video's frame
   times (its presentation times; 25 fps for GRID) to k/30 s; a 30 fps frame is *interpolated*
   when a source frame it is made from was; its confidence is its nearest source frame's.
   The clip lasts as long as the shorter of video and audio, in whole 30 fps frames.
4. **Audio**: decoded by FFmpeg (the ``imageio-ffmpeg`` binary) at its own rate, mixed to mono
   by FFmpeg, then resampled to the corpus rate by :func:`groundwork.audio.resample`
   (polyphase).
5. **Phones**: the transcript (a GRID ``.align``, a ``.txt`` beside the clip, or a CSV) aligned
   to the audio by the project's recogniser (:mod:`face_model.forced_align`, pocketsphinx), by
   one of two rules (:data:`ADMISSION_RULES`; ``corpus.json``'s ``admitted_by`` says which
   admitted each clip):

   - ``acoustic match``, a transcript without word times (``.txt`` or CSV: typed, so possibly
     wrong): aligned over the whole recording, and refused when it does not match the audio
     (its alignment scores more than ``MAX_SCORE_GAP`` per speech frame below free phone
     recognition, :func:`face_model.forced_align.align_audio`);
   - ``source word times``, a transcript that comes with the source's own word times (a GRID
     ``.align``): each word's phones aligned within its interval
     (:func:`face_model.forced_align.align_words`); refused unless the words, in time order,
     are the sentence's and every interval lies inside the audio
     (:meth:`face_model.transcripts.Transcript.check_word_times`). The acoustic comparison is
     not applied: it judges whether typed words were said, and on a speaker far from the US
     English model it refuses right ones (5 of GRID s26's 10 clips).

   A clip that ends before its transcript's times (a GRID ``.align``) do is refused as
   truncated, with the video's and the audio's lengths (:func:`check_length`): a ``.mpg`` cut
   to half its bytes decodes without complaint to half its length, and was blamed on its
   transcript.
6. **Words**: when the transcript gives the words' times (a GRID ``.align``), they are kept as
   ``words/<utt_id>.csv`` (``start_s,end_s,word``, seconds, silences ``sil``/``sp`` left out;
   :func:`face_model.corpus.write_words`), as the source gives them.

The corpus is built in a partial folder beside ``--out`` and renamed into place when every clip
is done and the whole folder has passed the corpus reader (:func:`face_model.corpus.load_corpus`);
an interrupted import resumes from the clips whose landmarks it already has. Each utterance gains
``quality/<utt_id>.csv`` (frame, confidence, interpolated), listed in the manifest's ``quality``
column; ``corpus.json`` says where the corpus came from, and ``refused.csv`` lists refused clips.
"""
from __future__ import annotations

import csv
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from face_model.corpus import FPS, QUALITY_COLUMNS, SUPPORTED_SR, write_utterance, write_words
from face_model.forced_align import MAX_SCORE_GAP, align_audio, align_words
from face_model.landmarks import Landmarks, markers_from_landmarks
from face_model.transcripts import END_TOLERANCE_S
from groundwork.audio import read_wav, resample
from groundwork.errors import CorpusError, ParameterError

VIDEO_EXTENSIONS = (".mpg", ".mpeg", ".mp4", ".m4v", ".avi", ".mov", ".mkv", ".webm")
AUDIO_FORMATS = ("wav", "flac")
ACOUSTIC_MATCH = "acoustic match"
SOURCE_WORD_TIMES = "source word times"
ADMISSION_RULES = {
    ACOUSTIC_MATCH: "a transcript without word times (.txt or CSV): phones aligned over the "
                    "whole recording; refused when the alignment scores more than "
                    f"{MAX_SCORE_GAP:g} per speech frame below free phone recognition "
                    "(face_model.forced_align.align_audio)",
    SOURCE_WORD_TIMES: "the source's own word times (.align): each word's phones aligned within "
                       "its interval (face_model.forced_align.align_words); refused unless the "
                       "words, in time order, are the sentence's and every interval lies inside "
                       "the audio; no comparison with free phone recognition",
}


@dataclass(frozen=True)
class FromVideoSettings:
    """How clips become utterances.

    Attributes
    ----------
    sample_rate : int
        The corpus's audio rate, Hz (one with an integer hop at 30 fps).
    max_missing_fraction : float
        Refuse a clip with more of its frames than this without a face.
    max_gap_s : float
        Refuse a clip with a longer run of frames without a face, seconds.
    speaker : str
        The manifest's speaker of every clip.
    expression : str
        The manifest's expression of every clip (``neutral`` for plain speech).
    audio_format : {"wav", "flac"}
        The audio files' format (both PCM16; FLAC is lossless and about half the size).
    max_multi_face_fraction : float
        Refuse a clip in which more of its frames than this show more than one face.
    max_roll_deg : float
        Refuse a clip whose face's median |roll| (in-plane rotation from upright) is larger,
        degrees. On 60 GRID s1 clips as recorded the clips' median |roll| was 0.3–4.1° (no
        frame's above 6.8°) and no frame showed a second face; upside down (``vflip``) the
        median |roll| was 173.9–177.5°, and two clips side by side (``hstack``) showed two faces
        in every frame (``python tools/face_checks_sweep.py ../shared/grid-s1/video``). 30°
        leaves room for a speaker's natural head tilt.
    """

    sample_rate: int = 22050
    max_missing_fraction: float = 0.10
    max_gap_s: float = 0.20
    speaker: str = "speaker"
    expression: str = "neutral"
    audio_format: str = "wav"
    max_multi_face_fraction: float = 0.10
    max_roll_deg: float = 30.0

    def check(self) -> "FromVideoSettings":
        if self.sample_rate not in SUPPORTED_SR:
            raise ParameterError(f"sample rate {self.sample_rate} Hz gives no integer hop at "
                                 f"{FPS} fps; allowed: {', '.join(map(str, SUPPORTED_SR))}")
        if not 0 <= self.max_missing_fraction < 1:
            raise ParameterError(f"max_missing_fraction {self.max_missing_fraction}; allowed: "
                                 "0 <= value < 1")
        if self.max_gap_s < 0:
            raise ParameterError(f"max_gap_s {self.max_gap_s}; allowed: >= 0 seconds")
        if not 0 <= self.max_multi_face_fraction < 1:
            raise ParameterError(f"max_multi_face_fraction {self.max_multi_face_fraction}; "
                                 "allowed: 0 <= value < 1")
        if not 0 < self.max_roll_deg < 180:
            raise ParameterError(f"max_roll_deg {self.max_roll_deg}; allowed: 0 < degrees < 180")
        if self.audio_format not in AUDIO_FORMATS:
            raise ParameterError(f"audio format {self.audio_format!r}; allowed: "
                                 f"{', '.join(AUDIO_FORMATS)}")
        return self


class ClipRefused(CorpusError):
    """One clip cannot become an utterance (the reason is the message)."""


def find_videos(src) -> list[Path]:
    """The videos of ``src`` (a video file or a folder of them, not recursive), sorted.

    Raises
    ------
    ParameterError
        ``src`` is missing, or a folder with no file of :data:`VIDEO_EXTENSIONS`.
    """
    src = Path(src)
    if src.is_file():
        return [src]
    if not src.is_dir():
        raise ParameterError(f"{src}: no such file or folder")
    videos = sorted(p for p in src.iterdir()
                    if p.is_file() and p.suffix.lower() in VIDEO_EXTENSIONS)
    if not videos:
        raise ParameterError(f"{src}: no videos in this folder (allowed extensions: "
                             f"{' '.join(VIDEO_EXTENSIONS)})")
    return videos


def default_speaker(src) -> str:
    """The speaker named by the source: its folder's name (the parent's for a ``video`` folder
    such as GRID's ``s1/video``)."""
    src = Path(src).resolve()
    folder = src.parent if src.is_file() else src
    return folder.parent.name if folder.name.lower() in ("video", "videos") else folder.name


def fill_gaps(values: np.ndarray, found: np.ndarray) -> np.ndarray:
    """``values`` (n, ...) with the rows where ``found`` is false replaced by linear
    interpolation between the nearest found rows (held at the ends)."""
    v = np.asarray(values, dtype=np.float64)
    idx = np.flatnonzero(found)
    if len(idx) == len(v):
        return v.copy()
    flat = v.reshape(len(v), -1)
    out = np.empty_like(flat)
    frames = np.arange(len(v))
    for c in range(flat.shape[1]):
        out[:, c] = np.interp(frames, idx, flat[idx, c])
    return out.reshape(v.shape)


def longest_run(mask: np.ndarray) -> tuple[int, int]:
    """``(start, length)`` of the longest run of true values (``(0, 0)`` when none)."""
    best, start = (0, 0), None
    for i, m in enumerate(list(mask) + [False]):
        if m and start is None:
            start = i
        elif not m and start is not None:
            if i - start > best[1]:
                best = (start, i - start)
            start = None
    return best


def resample_track(values: np.ndarray, times_s: np.ndarray, n_out: int,
                   fps: int = FPS) -> np.ndarray:
    """Linear interpolation in time of ``values`` (n_in, ...) at ``times_s`` to frames k/fps,
    k < ``n_out`` (held at the first and last value outside the source's times)."""
    v = np.asarray(values, dtype=np.float64)
    t = np.asarray(times_s, dtype=np.float64)
    if len(t) != len(v) or len(t) < 1 or np.any(np.diff(t) <= 0):
        raise ParameterError(f"frame times must be increasing, one per frame; got {len(t)} times "
                             f"for {len(v)} frames")
    t_out = np.arange(n_out) / fps
    flat = v.reshape(len(v), -1)
    out = np.stack([np.interp(t_out, t, flat[:, c]) for c in range(flat.shape[1])], axis=1)
    return out.reshape((n_out,) + v.shape[1:])


def source_frames(times_s: np.ndarray, n_out: int, fps: int = FPS) -> tuple[np.ndarray,
                                                                          np.ndarray]:
    """For each output frame k/fps: the source frames before and after it (equal at the ends)."""
    t_out = np.arange(n_out) / fps
    after = np.searchsorted(times_s, t_out, side="left").clip(0, len(times_s) - 1)
    before = np.where(times_s[after] > t_out, after - 1, after).clip(0, len(times_s) - 1)
    return before, after


def decode_audio(video: Path, sample_rate: int, scratch: Path) -> np.ndarray:
    """Mono audio of ``video`` at ``sample_rate`` (FFmpeg decodes and mixes to mono at the
    clip's own rate; :func:`groundwork.audio.resample` does the rest)."""
    import imageio_ffmpeg  # noqa: PLC0415 (the FFmpeg binary, only when decoding)
    wav = scratch / f"{video.stem}.wav"
    cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-nostdin", "-v", "error", "-y", "-i", str(video),
           "-vn", "-ac", "1", "-acodec", "pcm_s16le", str(wav)]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0 or not wav.is_file() or wav.stat().st_size <= 44:
        why = (res.stderr.strip().splitlines() or ["no audio stream"])[-1]
        if "does not contain any stream" in why or "matches no streams" in why or res.returncode == 0:
            why = "no audio stream"
        raise ClipRefused(f"{video}: no audio could be decoded ({why})")
    try:
        y, sr = read_wav(wav)
    finally:
        wav.unlink(missing_ok=True)
    if len(y) == 0:
        raise ClipRefused(f"{video}: no audio stream")
    return resample(y, sr_in=sr, sr_out=sample_rate) if sr != sample_rate else y


def face_orientation(lm: Landmarks) -> tuple[float, float]:
    """``(share, roll)``: the share of the clip's frames in which the detector counted more than
    one face, and the median |roll| in degrees over the frames with a detection (NaN: none, or
    unknown in an older landmark file; the share is then 0)."""
    share = float(np.mean(lm.n_faces > 1)) if lm.n_faces is not None and len(lm.n_faces) else 0.0
    roll = np.abs(lm.roll_deg[~np.isnan(lm.roll_deg)]) if lm.roll_deg is not None else []
    return share, float(np.median(roll)) if len(roll) else float("nan")


def check_face(video: Path, lm: Landmarks, settings: FromVideoSettings) -> None:
    """Refuse a clip whose face is missed too often, or is not one upright face (see the
    module text)."""
    n = len(lm.found)
    missed = int(n - lm.found.sum())
    if missed == n:
        raise ClipRefused(f"{video}: no face found in any of its {n} frames")
    share, roll = face_orientation(lm)
    if share > settings.max_multi_face_fraction:
        many = int(np.sum(lm.n_faces > 1))
        raise ClipRefused(f"{video}: {many} of {n} frames show more than one face "
                          f"({100 * share:.0f} %); allowed: one speaker's face (more than one "
                          f"face in at most {100 * settings.max_multi_face_fraction:.0f} % of "
                          "frames) — crop the video to the speaker's face")
    if roll > settings.max_roll_deg:
        raise ClipRefused(f"{video}: the face is turned {roll:.0f}° from upright (median |roll| "
                          f"over its frames); allowed: at most {settings.max_roll_deg:g}° — turn "
                          "the video upright")
    if missed > settings.max_missing_fraction * n:
        raise ClipRefused(f"{video}: {missed} of {n} frames without a face "
                          f"({100 * missed / n:.0f} %); allowed: at most "
                          f"{100 * settings.max_missing_fraction:.0f} %")
    start, length = longest_run(~lm.found)
    dt = float(np.median(np.diff(lm.time_s))) if n > 1 else 0.0
    if length * dt > settings.max_gap_s + 1e-9:
        raise ClipRefused(f"{video}: {length} frames in a row without a face (frames "
                          f"{start}–{start + length - 1}, {length * dt:.2f} s); allowed: at most "
                          f"{settings.max_gap_s:.2f} s")


def clip_tracks(lm: Landmarks, n_out: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(markers (n_out, 79, 2), confidence (n_out,), interpolated (n_out,))`` at 30 fps."""
    markers = fill_gaps(markers_from_landmarks(np.nan_to_num(lm.points)), lm.found)
    out = resample_track(markers, lm.time_s, n_out)
    before, after = source_frames(lm.time_s, n_out)
    t_out = np.arange(n_out) / FPS
    nearest = np.where(np.abs(lm.time_s[after] - t_out) < np.abs(lm.time_s[before] - t_out),
                       after, before)
    interpolated = ~(lm.found[before] & lm.found[after])
    return out.astype(np.float32), lm.confidence[nearest].astype(np.float64), interpolated


def write_quality(path: Path, confidence: np.ndarray, interpolated: np.ndarray) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(QUALITY_COLUMNS)
        for k, (c, i) in enumerate(zip(confidence, interpolated)):
            w.writerow([k, f"{c:.4f}", int(bool(i))])


@dataclass(frozen=True)
class ClipData:
    """One clip at 30 fps: audio at the corpus rate and the face's tracks."""

    video: Path
    audio: np.ndarray
    sample_rate: int
    markers: np.ndarray  # (n_frames, 79, 2) float32, image pixels
    confidence: np.ndarray  # (n_frames,)
    interpolated: np.ndarray  # (n_frames,) bool
    video_s: float = 0.0  # the decoded video's length, seconds
    video_frames: int = 0  # its frames, at its own rate
    audio_s: float = 0.0  # the decoded audio's length, seconds

    @property
    def n_frames(self) -> int:
        return len(self.markers)


def clip_data(video: Path, landmark_file: Path, settings: FromVideoSettings,
              scratch: Path) -> ClipData:
    """A clip's audio and 30 fps tracks from its video and landmark file.

    Raises
    ------
    ClipRefused
        Its face or audio (the message says which and why).
    """
    try:
        lm = Landmarks.load(landmark_file)
    except (OSError, ValueError, KeyError) as exc:
        raise ClipRefused(f"{video}: its landmark file {landmark_file} is unreadable ({exc})")
    check_face(video, lm, settings)
    with tempfile.TemporaryDirectory(dir=scratch) as tmp:
        y = decode_audio(video, settings.sample_rate, Path(tmp))
    sr = settings.sample_rate
    dt = float(np.median(np.diff(lm.time_s))) if len(lm.time_s) > 1 else 1 / FPS
    video_s = float(lm.time_s[-1] - lm.time_s[0] + dt)
    audio_s = len(y) / sr
    n_out = int(np.floor(min(video_s, audio_s) * FPS + 1e-6))
    if n_out < 2:
        raise ClipRefused(f"{video}: {min(video_s, audio_s):.3f} s of video with audio; "
                          f"allowed: at least 2 frames at {FPS} fps")
    n_samples = int(round(n_out * sr / FPS))
    y = np.pad(y[:n_samples], (0, max(0, n_samples - len(y))))
    markers, confidence, interpolated = clip_tracks(lm, n_out)
    return ClipData(video, y, sr, markers, confidence, interpolated, video_s, len(lm.found),
                    audio_s)


def check_length(clip: ClipData, transcript) -> None:
    """Refuse a clip that ends before its transcript's times do (a file cut short, e.g. an
    interrupted download or copy, or another recording's transcript), naming the video and its
    lengths rather than blaming the transcript.

    Raises
    ------
    ClipRefused
        The transcript (a GRID ``.align``) ends more than
        :data:`face_model.transcripts.END_TOLERANCE_S` after the shorter of video and audio.
    """
    end = getattr(transcript, "end_s", None)
    usable = clip.n_frames / FPS
    if end is None or end <= usable + END_TOLERANCE_S:
        return
    raise ClipRefused(
        f"{clip.video}: the video is truncated or shorter than its transcript's timing: its "
        f"picture lasts {clip.video_s:.2f} s ({clip.video_frames} frames) and its audio "
        f"{clip.audio_s:.2f} s, but {transcript.source} runs to {end:.2f} s; allowed: the "
        f"transcript ending at most {END_TOLERANCE_S:g} s after the clip (check that the file "
        "was copied or downloaded whole and that the transcript is this recording's)")


def transcript_phones(y: np.ndarray, sr: int, transcript, duration_s: float, *,
                      source: str) -> tuple[list, str, tuple]:
    """A clip's phones from its transcript, by the rule its transcript falls under (module text,
    step 5).

    Parameters
    ----------
    y : ndarray, shape (n,)
        Mono audio in [-1, 1].
    sr : int
        Its sample rate, Hz.
    transcript : face_model.transcripts.Transcript
    duration_s : float
        The clip's length (its whole 30 fps frames), seconds.
    source : str
        The clip's file, for messages.

    Returns
    -------
    phones : list of PhoneSegment
    rule : str
        :data:`SOURCE_WORD_TIMES` when the transcript gives its words' times, else
        :data:`ACOUSTIC_MATCH`.
    even : tuple of str
        The words whose phones divide their interval evenly (the aligner found no path within
        it; :class:`face_model.forced_align.WordTimedAlignment`), in order; empty under
        :data:`ACOUSTIC_MATCH`.

    Raises
    ------
    CorpusError
        The transcript refused by its rule (the message says why).
    """
    if transcript.words:
        transcript.check_word_times(duration_s, source=source)
        timed = align_words(y, sr, transcript.words, source=source)
        return timed.phones, SOURCE_WORD_TIMES, tuple(w for _, w in timed.even)
    return align_audio(y, sr, transcript.text, source=source), ACOUSTIC_MATCH, ()


def make_utterance(video: Path, landmark_file: Path, transcript, root: Path,
                   settings: FromVideoSettings) -> dict:
    """One clip → one utterance's files under ``root``; its manifest row.

    Raises
    ------
    ClipRefused
        Its face, audio or transcript (the message says which and why).
    """
    clip = clip_data(video, landmark_file, settings, root)
    y, sr, n_out = clip.audio, clip.sample_rate, clip.n_frames
    check_length(clip, transcript)
    transcript.check_duration(n_out / FPS, source=str(video))
    phones, rule, even = transcript_phones(y, sr, transcript, n_out / FPS, source=str(video))
    utt_id = video.stem
    rel = write_utterance(root, utt_id=utt_id, audio=y, sr=sr, markers=clip.markers,
                          phones=phones)
    if settings.audio_format == "flac":
        import soundfile as sf  # noqa: PLC0415
        wav = root / rel["audio"]
        rel["audio"] = f"audio/{utt_id}.flac"
        sf.write(root / rel["audio"], (np.clip(y, -1, 1) * 32767).round().astype(np.int16),
                 sr, subtype="PCM_16")
        wav.unlink()
    (root / "quality").mkdir(exist_ok=True)
    rel["quality"] = f"quality/{utt_id}.csv"
    write_quality(root / rel["quality"], clip.confidence, clip.interpolated)
    if transcript.words:
        write_words(root, utt_id, transcript.words)
    return {"utt_id": utt_id, "speaker": settings.speaker, "expression": settings.expression,
            "text": transcript.text, "n_frames": n_out, "fps": FPS, "sample_rate": sr, **rel,
            "admitted_by": rule, "even_words": list(even)}  # corpus.json keeps these two
