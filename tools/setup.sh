#!/usr/bin/env bash
# Everything `make replicate`, `make server` and `make test` need, on a fresh Debian/Ubuntu
# machine: missing Debian packages (apt-get, with sudo when not root), a .venv, and the pinned
# Python packages (torch==2.13.0 through requirements/constraints.txt, the rest from
# requirements/lock.txt).
#
#   bash tools/setup.sh          base: what the replication needs (`make replicate`)
#   bash tools/setup.sh server   base + the lab's tracking server (`make server`): Debian
#                                postgresql, and requirements/lab.txt (psycopg 3)
#   bash tools/setup.sh face     base + the face environment (`$VENV-face`, requirements/face.txt):
#                                MediaPipe Face Mesh for landmarks from real video
#                                (`talkingface corpus from-video`, `talkingface evaluate-face`)
#   bash tools/setup.sh web      base + the web study's page (`talkingface study web`): Debian
#                                nodejs and npm when node or npm is missing, and jsPsych with its
#                                plugins, pinned by study/web/package-lock.json, in
#                                study/web/node_modules (`npm ci`)
#   bash tools/setup.sh test     base + server + face + web + what the tests need (`make test`):
#                                Debian chromium and chromium-driver, and requirements/lab.txt
#                                (selenium)
#
# Re-running is cheap: the venv is rebuilt only when the lock file or pyproject changes, the
# lab's extras are reinstalled only when requirements/lab.txt (or what it is pinned against) does
# (one stamp file each in the venv), and study/web/node_modules only when
# study/web/package-lock.json does (a stamp file in node_modules).
set -euo pipefail
cd "$(dirname "$0")/.."

MODE=${1:-base}
case "$MODE" in
  base|server|face|web|test) ;;
  *) echo "setup: unknown mode '$MODE'; allowed: base (the default), server, face, web, test" >&2
     exit 2;;
esac
VENV=${VENV:-.venv}
PY=${PYTHON:-python3}
# Debian packages: Python with venv and pip; flite (the optional second speech backend and its
# voices kal, kal16, awb, rms, slt, tested); festival with its three English voices
# festvox-kallpc16k, festvox-kdlpc16k, festvox-us-slt-hts and the lexicons they need,
# festlex-cmu, festlex-poslex (the `synth.voices` festival:* voices, tested);
# libgl1 (OpenCV, the tracker); ffmpeg (ffprobe checks the MP4s that animate writes, in tests);
# libportaudio2 (sounddevice: `talkingface stream --mic`, PsychoPy sound; tested on ALSA's null
# device; it brings ALSA); libjack-jackd2-0 (PsychoPy audio); xvfb, xauth (headless sessions).
DEB_PKGS="python3 python3-venv python3-pip flite festival festlex-cmu festlex-poslex
  festvox-kallpc16k festvox-kdlpc16k festvox-us-slt-hts libgl1 ffmpeg libportaudio2
  libjack-jackd2-0 xvfb xauth"
# server and test: postgresql (the lab's tracking server keeps its runs in it: `talkingface server`).
# test: chromium and chromium-driver (the MLflow UI opened in a real, headless browser).
case "$MODE" in server|test) DEB_PKGS="$DEB_PKGS postgresql";; esac
if [ "$MODE" = test ]; then DEB_PKGS="$DEB_PKGS chromium chromium-driver"; fi
# web and test: nodejs and npm (jsPsych's packages, the page's simulation tests), unless a node
# and an npm are already on the PATH (e.g. from nodesource or nvm).
if [ "$MODE" = web ] || [ "$MODE" = test ]; then
  { command -v node && command -v npm; } >/dev/null 2>&1 || DEB_PKGS="$DEB_PKGS nodejs npm"
fi

missing=()
for p in $DEB_PKGS; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
# A Python from elsewhere (pyenv, a conda base) with venv support is fine for the python3* trio.
if "$PY" -c 'import venv, ensurepip' 2>/dev/null; then
  keep=(); for p in "${missing[@]:-}"; do case "$p" in python3*|"") ;; *) keep+=("$p");; esac; done
  missing=("${keep[@]:-}")
fi
if [ -n "${missing[*]:-}" ]; then
  echo "setup: installing Debian packages: ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
fi

"$PY" - <<'PYV'
import sys
if not ((3, 10) <= sys.version_info[:2] <= (3, 12)):
    sys.exit(f"setup: Python 3.10-3.12 is required, found {sys.version.split()[0]}")
PYV

STAMP="$VENV/.talkingface-installed"
want=$(cat requirements/lock.txt requirements/constraints.txt pyproject.toml | sha256sum | cut -d' ' -f1)
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$want" ]; then
  [ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  # torch first, from its pin, so nothing can pull a CUDA build.
  "$VENV/bin/python" -m pip install -q -c requirements/constraints.txt "torch==2.13.0"
  "$VENV/bin/python" -m pip install -q -c requirements/constraints.txt -r requirements/lock.txt
  "$VENV/bin/python" -m pip install -q --no-deps -e .
  echo "$want" > "$STAMP"
  echo "setup: $VENV ready"
fi

# The lab's extras (server and test modes), pinned against the lock file: what they share with
# it stays at the lock's versions.
if [ "$MODE" = server ] || [ "$MODE" = test ]; then
  LAB_STAMP="$VENV/.talkingface-lab-installed"
  want_lab=$(cat requirements/lab.txt requirements/lock.txt requirements/constraints.txt \
    | sha256sum | cut -d' ' -f1)
  if [ ! -f "$LAB_STAMP" ] || [ "$(cat "$LAB_STAMP")" != "$want_lab" ]; then
    "$VENV/bin/python" -m pip install -q -c requirements/constraints.txt \
      -c requirements/lock.txt -r requirements/lab.txt
    echo "$want_lab" > "$LAB_STAMP"
    echo "setup: the lab's extras (requirements/lab.txt) ready in $VENV"
  fi
fi

# The face environment (face and test modes): MediaPipe beside its own protobuf 4.25, which the
# project's lock (protobuf 7) cannot hold; the project runs its Python as a subprocess
# (face_model/landmark_worker.py). requirements/face.txt is complete, hence --no-deps.
if [ "$MODE" = face ] || [ "$MODE" = test ]; then
  FACE_VENV="${FACE_VENV:-$VENV-face}"
  FACE_STAMP="$FACE_VENV/.talkingface-face-installed"
  want_face=$(cat requirements/face.txt | sha256sum | cut -d' ' -f1)
  if [ ! -f "$FACE_STAMP" ] || [ "$(cat "$FACE_STAMP")" != "$want_face" ]; then
    [ -x "$FACE_VENV/bin/python" ] || "$PY" -m venv "$FACE_VENV"
    "$FACE_VENV/bin/python" -m pip install -q --upgrade pip
    "$FACE_VENV/bin/python" -m pip install -q --no-deps -r requirements/face.txt
    "$FACE_VENV/bin/python" -c "import mediapipe, cv2; mediapipe.solutions.face_mesh.FaceMesh" \
      || { echo "setup: the face environment $FACE_VENV does not import mediapipe" >&2; exit 1; }
    echo "$want_face" > "$FACE_STAMP"
    echo "setup: the face environment (requirements/face.txt) ready in $FACE_VENV"
  fi
fi

# The web study (web and test modes): jsPsych and its plugins exactly as package-lock.json pins
# them (`npm ci` removes node_modules first, so nothing else stays in it).
if [ "$MODE" = web ] || [ "$MODE" = test ]; then
  WEB_STAMP=study/web/node_modules/.talkingface-web-installed
  want_web=$(sha256sum study/web/package-lock.json | cut -d' ' -f1)
  if [ ! -f "$WEB_STAMP" ] || [ "$(cat "$WEB_STAMP")" != "$want_web" ]; then
    npm ci --prefix study/web --no-audit --no-fund --loglevel=error
    echo "$want_web" > "$WEB_STAMP"
    echo "setup: the web study's jsPsych (study/web/package-lock.json) ready in study/web/node_modules"
  fi
fi
