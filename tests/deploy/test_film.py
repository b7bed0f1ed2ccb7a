"""``kinesphere film``: the paper's Left-High phrase on every body, as MP4 and GIF."""

from __future__ import annotations

import math
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest
from PIL import Image
from PIL.GifImagePlugin import GifImageFile

from kinesphere.clients.orders import score_play
from kinesphere.clients.orders.phrases import load_phrase
from kinesphere.deploy.film import CAPTION_H, HOLD_S, PLATFORMS, UPBEAT_S, render
from kinesphere.errors import KinesphereError
from support.paths import ROOT

PHRASE = ROOT / "clients" / "phrases" / "left_high.toml"
W, H, FPS = 96, 80, 6.0


@pytest.mark.processes  # ffmpeg encodes the film
def test_left_high_film(tmp_path: Path) -> None:
    mp4, gif = tmp_path / "left_high.mp4", tmp_path / "left_high.gif"
    n = render(PHRASE, mp4, gif, PLATFORMS, W, H, FPS)
    expected = math.ceil(load_phrase(PHRASE).duration * FPS)
    assert n == expected
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


@pytest.mark.processes  # ffmpeg encodes the film
def test_a_score_film_shows_every_body_performing_it(tmp_path: Path) -> None:
    """``think_d_high_s``: both hands up to the chin, the body turned 60 degrees right, and
    back; each body moves (the one-armed ones at least turn), the frames span the score."""
    mp4 = tmp_path / "think.mp4"
    n = render("think_d_high_s", mp4, None, PLATFORMS, W, H, FPS, speed=2.0)
    score = score_play.load("think_d_high_s").gestures[0]
    span = (score.keyframes[-1].time_ms - score.keyframes[0].time_ms) / 1e3 / 2.0
    assert n == math.ceil((UPBEAT_S + span + HOLD_S) * FPS)
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
