"""``kinesphere film``: the paper's Left-High phrase on every body, as MP4 and GIF."""

from __future__ import annotations

import math
import signal
import subprocess
import sys
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest
from PIL import Image
from PIL.GifImagePlugin import GifImageFile

from kinesphere.clients.orders import score_play
from kinesphere.clients.orders.phrases import load_phrase
from kinesphere.deploy.film import (
    CAPTION_H,
    HOLD_S,
    PLATFORMS,
    REST_S,
    SETTLE_MAX_S,
    UPBEAT_S,
    render,
)
from kinesphere.errors import KinesphereError
from support.paths import ROOT
from support.system import ctrl_c_reaches_it
from support.wait import WAIT_S

PHRASE = ROOT / "clients" / "phrases" / "left_high.toml"
W, H, FPS = 96, 80, 6.0


@pytest.mark.processes  # ffmpeg encodes the film
def test_left_high_film(tmp_path: Path) -> None:
    mp4, gif = tmp_path / "left_high.mp4", tmp_path / "left_high.gif"
    n = render(PHRASE, mp4, gif, PLATFORMS, W, H, FPS)
    phrase = math.ceil(load_phrase(PHRASE).duration * FPS)
    assert phrase < n <= phrase + (SETTLE_MAX_S + REST_S) * FPS + 1, "the phrase, then rest"
    expected = n
    reader = imageio_ffmpeg.read_frames(str(mp4))
    meta = reader.__next__()
    assert tuple(meta["size"]) == (W * len(PLATFORMS), H + CAPTION_H)
    video = [np.frombuffer(f, np.uint8).reshape(H + CAPTION_H, W * len(PLATFORMS), 3)
             for f in reader]
    assert len(video) == expected
    with Image.open(gif) as g:
        assert isinstance(g, GifImageFile) and g.n_frames == expected
    first, middle = video[0].astype(int), video[len(video) // 2].astype(int)
    for j, name in enumerate(PLATFORMS):  # every robot's pixels change: each body moved
        tile = np.s_[CAPTION_H + 16 : H + CAPTION_H - 20, j * W : (j + 1) * W]
        changed = (np.abs(middle[tile] - first[tile]).max(axis=2) > 40).sum()
        assert changed > 30, f"{name} did not move between the first and middle frames"
    last, before = video[-1].astype(int), video[-2].astype(int)
    for j, name in enumerate(PLATFORMS):  # the film ends with every body at rest
        tile = np.s_[CAPTION_H + 16 : H + CAPTION_H - 20, j * W : (j + 1) * W]
        assert (np.abs(last[tile] - before[tile]).max(axis=2) > 40).sum() == 0, name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["left_high.gif", "left_high.mp4"]


@pytest.mark.processes  # ffmpeg encodes the film
def test_a_score_film_shows_every_body_performing_it(tmp_path: Path) -> None:
    """``think_d_high_s``: both hands up to the chin, the body turned 60 degrees right, and
    back; each body moves (the one-armed ones at least turn), the frames span the score."""
    mp4 = tmp_path / "think.mp4"
    n = render("think_d_high_s", mp4, None, PLATFORMS, W, H, FPS, speed=2.0)
    score = score_play.load("think_d_high_s").gestures[0]
    span = (score.keyframes[-1].time_ms - score.keyframes[0].time_ms) / 1e3 / 2.0
    assert n >= math.ceil((UPBEAT_S + span + HOLD_S) * FPS)  # and the bodies coming to rest
    reader = imageio_ffmpeg.read_frames(str(mp4))
    reader.__next__()
    video = [np.frombuffer(f, np.uint8).reshape(H + CAPTION_H, W * len(PLATFORMS), 3)
             for f in reader]
    assert len(video) == n
    first, turned = video[0].astype(int), video[round((UPBEAT_S + 0.6) * FPS)].astype(int)
    for j, name in enumerate(PLATFORMS):
        tile = np.s_[CAPTION_H + 16 : H + CAPTION_H - 20, j * W : (j + 1) * W]
        changed = (np.abs(turned[tile] - first[tile]).max(axis=2) > 40).sum()
        assert changed > 30, f"{name} did not move for the score"
    with pytest.raises(KinesphereError, match="no gesture 'wave'"):
        render("think_d_high_s", mp4, None, PLATFORMS, W, H, FPS, gesture="wave")


@pytest.mark.processes
def test_an_interrupted_film_leaves_no_partial_file(tmp_path: Path) -> None:
    """Ctrl-C while the frames are being encoded: exit 130, a message, and no file at all
    (the film is written aside and renamed only when whole). The Ctrl-C comes when the film
    says its second step starts: the first step's 30 frames are in the encoder, the second's
    and the rest's (at least 35) not yet rendered."""
    out = tmp_path / "film.mp4"
    proc = subprocess.Popen(
        [sys.executable, "-m", "kinesphere.cli", "film", str(PHRASE), "-o", str(out),
         "--width", "96", "--height", "80", "--fps", "10", "--bodies", "youbot"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=ctrl_c_reaches_it)
    said: list[str] = []
    try:
        assert proc.stderr is not None
        for row in proc.stderr:  # ends when the film does: then the assertions below say so
            said.append(row)
            if "step 2/2" in row:
                assert list(tmp_path.glob(".film.*.partial.mp4")), "the film is being written"
                break
    finally:
        proc.send_signal(signal.SIGINT)
        _, rest = proc.communicate(timeout=WAIT_S)
    err = "".join(said) + rest
    assert any("step 2/2" in row for row in said), err
    assert proc.returncode == 130, err
    assert f"film interrupted: nothing written to {out}" in err
    assert list(tmp_path.iterdir()) == [], "no partial MP4 or GIF left behind"
    assert "OpenGL" not in err, "no chatter of the libraries"
