"""`umf serve` in a real headless Chromium, driven by playwright-core (tests/browser): a user
types a prompt for 3 people, clicks Generate and sees three differently coloured figures
that the scrubber moves; the GLB download is a valid GLB; the console stays clean.

Needs Debian's chromium (`.ci/run` installs it) and node with playwright-core (`make
install` puts it under .venv/node); skips, saying which is missing, only without them.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from matplotlib.colors import rgb_to_hsv, to_rgb

from umf.render import PALETTE

REPO = Path(__file__).resolve().parents[1]
DRIVER = REPO / "tests" / "browser" / "serve_e2e.cjs"
PLAYWRIGHT = next(
    (p for p in (Path(sys.prefix), REPO / ".venv")
     if (p / "node" / "node_modules" / "playwright-core").is_dir()), REPO / ".venv"
) / "node" / "node_modules" / "playwright-core"  # fmt: skip
CHROMIUM = Path(os.environ.get("CHROMIUM", "/usr/bin/chromium"))
MIN_FIGURE_PIXELS = 150  # a figure at the test's framing covers thousands


def _missing() -> str | None:
    if not CHROMIUM.exists():
        return f"{CHROMIUM} not installed (.ci/run installs Debian's chromium)"
    if shutil.which("node") is None:
        return "node not installed"
    if not PLAYWRIGHT.is_dir():
        return f"playwright-core not installed under {PLAYWRIGHT.parent} (make install)"
    return None


@pytest.fixture(scope="module")
def served():
    """`umf serve --port 0` as a user starts it; yields its URL (read from its first line)."""
    reason = _missing()
    if reason:
        print(f"skipping the browser test: {reason}")
        pytest.skip(reason)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "umf.cli.main", "serve", "--port", "0", "--no-open"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=REPO,
    )  # fmt: skip
    line = proc.stdout.readline()
    if not line.startswith("umf serve: http://"):
        proc.kill()
        pytest.fail(f"umf serve did not start: {line}{proc.stderr.read()}")
    yield line.split()[2]
    proc.terminate()
    proc.wait(timeout=10)


@pytest.fixture(scope="module")
def browsed(served, tmp_path_factory):
    """Run the browser driver once; its snapshots, download and result.json."""
    out = tmp_path_factory.mktemp("browser")
    env = {**os.environ, "PLAYWRIGHT_CORE": str(PLAYWRIGHT), "CHROMIUM": str(CHROMIUM)}
    r = subprocess.run(["node", str(DRIVER), served, str(out)], capture_output=True, text=True,
                       env=env, timeout=900)  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads((out / "result.json").read_text())
    print(f"first scene shown {result['click_to_scene_s']:.1f} s after the click; "
          f"screenshot {out / 'page.png'}")  # fmt: skip
    return out, result


def hue_pixels(image: np.ndarray, colour: str) -> int:
    """Pixels of the colour's hue (any shade the lighting gives), saturated enough not to be
    the grey floor, grid, background or shadows."""
    hsv = rgb_to_hsv(image[..., :3] / 255.0)
    target = rgb_to_hsv(np.array(to_rgb(colour)))[0]
    distance = np.abs((hsv[..., 0] - target + 0.5) % 1.0 - 0.5)
    return int(((distance < 0.04) & (hsv[..., 1] > 0.35) & (hsv[..., 2] > 0.15)).sum())


def test_three_coloured_figures_on_the_canvas(browsed):
    out, result = browsed
    assert result["errors"] == [], result["errors"]
    assert result["people"] == list(PALETTE[:3])  # the viewer found one mesh per person
    assert result["labels"] == ["P1", "P2", "P3"]
    for name in ("frame-first.png", "frame-last.png"):
        canvas = iio.imread(out / name)
        counts = [hue_pixels(canvas, c) for c in PALETTE[:3]]
        assert min(counts) > MIN_FIGURE_PIXELS, (name, counts)
    assert result["history"] and "Three people walk side by side." in result["history"][0]
    # one box per person; the filled one reached the model as person 2's own prompt
    assert result["person_boxes"] == 3
    assert result["person_prompts"] == [None, "Someone bows politely.", None]


def test_the_scrubber_moves_the_figures(browsed):
    out, result = browsed
    assert result["frames"] == 120
    first = iio.imread(out / "frame-first.png").astype(int)
    last = iio.imread(out / "frame-last.png").astype(int)
    assert first.shape == last.shape
    changed = (np.abs(first - last).max(axis=-1) > 30).mean()
    assert changed > 0.002, changed  # the figures moved (the camera stays put)


def test_the_glb_download_is_a_valid_glb(browsed):
    out, result = browsed
    data = (out / "download.glb").read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    size, kind = struct.unpack_from("<I4s", data, 12)
    doc = json.loads(data[20 : 20 + size])
    assert kind == b"JSON" and len(doc["skins"]) == 3 and doc["animations"][0]["name"] == "umf"
    assert doc["asset"]["extras"]["text"] == "Three people walk side by side."
    assert result["download_name"].endswith(".glb")


def test_rerolling_person_2_keeps_the_others(browsed):
    """The page's re-roll button of person 2: a new scene in the history, persons 1 and 3
    the same joints as before (the API's mm-rounded copy), person 2 new."""
    _, result = browsed
    assert result["errors"] == [], result["errors"]
    assert result["reroll_buttons"] == ["P1", "P2", "P3"]
    r = result["reroll"]
    assert r["from"] != r["to"] and r["same"] == [True, False, True], r
    assert "Person 2 re-rolled" in r["status"]
    assert "P2 re-rolled" in r["history"][0] and len(r["history"]) == len(result["history"]) + 1
