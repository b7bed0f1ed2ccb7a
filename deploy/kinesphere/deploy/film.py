"""``kinesphere film PHRASE``: a movement phrase performed by every body side by side, on video.

The paper's raters watched robots perform movement phrases; a film makes that evaluation
repeatable. Each platform is a real agent controller (MuJoCo model, Ruckig trajectories, the
same base controllers) stepped in robot time, its targets answered by its real ECL in
process, exactly as the agent would get them from the databank. Frames are MuJoCo off-screen
renders (``MUJOCO_GL=egl``) with the ECL's camera, composed side by side with a caption of
the current command in words, and written as MP4 (ffmpeg from imageio-ffmpeg) and GIF.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from kinesphere.deploy.plan import DEFAULT_ROBOTS
from kinesphere.errors import KinesphereError

log = logging.getLogger(__name__)
PLATFORMS: Final = DEFAULT_ROBOTS
"""Every shipped body, as ``kinesphere up`` starts them."""
CONTROL_HZ: Final = 250.0
CAPTION_H: Final = 40


@dataclass
class Performer:
    """One body performing the phrase: its controller, ECL, camera and alias names."""

    name: str
    controller: Any
    ecl: Any
    camera: Any
    names: dict[str, str]
    note: str = ""


def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=size)
    except TypeError:
        return ImageFont.load_default()


def _performers(platforms: Sequence[str], phrase: Any, width: int, height: int
                ) -> list[Performer]:
    from kinesphere.platforms.mjcf import platform_model
    from kinesphere.robots.agent.bodies import make_body
    from kinesphere.robots.agent.controller import Controller
    from kinesphere.services.ecl.ecl import Ecl
    from kinesphere.services.ecl.render import Camera, frame, pose_qpos
    from kinesphere.words import label_names

    out = []
    for name in platforms:
        pm = platform_model(name)
        ecl = Ecl.open(name)
        targets = []
        for step in phrase.steps:
            try:
                targets.append(pose_qpos(pm, _resolve(ecl, step.parts)))
            except KinesphereError:
                pass
        body = make_body("mujoco", name, 1.0 / CONTROL_HZ)  # the agent's default body
        out.append(Performer(name, Controller(body), ecl,
                             Camera(pm, width, height, frame(pm, targets)),
                             label_names(pm.platform.eurdf.aliases)))
    return out


def _resolve(ecl: Any, parts: Sequence[Any]) -> Any:
    if len(parts) == 1:
        p = parts[0]
        return ecl.query(p.limb, p.origin, p.direction, p.size)
    return ecl.compound(parts)


def _start(p: Performer, step: Any) -> None:
    """Send one step to a body the way the agent applies a command."""
    from kinesphere.laban import Direction

    ctrl = p.controller
    base = ctrl.base
    p.note = ""
    if step.drive is not None and base is not None:
        base.drive(Direction.parse(step.drive.direction).vector[:2], step.drive.speed)
    elif base is not None and base.driving:
        base.stop()
    if not step.parts:
        return
    try:
        pose = _resolve(p.ecl, step.parts)
    except KinesphereError as exc:
        p.note = f"{exc.code}: holds"
        return
    ctrl.joints.retarget(pose.joints)
    if pose.translation is not None and base is not None and not base.driving:
        base.translate(pose.translation, ctrl.commanded_base_yaw())
    if pose.substitutions:
        p.note = ", ".join(f"{s.requested} → {s.served}" for s in pose.substitutions)


def _caption(text: str, width: int) -> Image.Image:
    img = Image.new("RGB", (width, CAPTION_H), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    draw.text((6, 4), text, fill=(20, 20, 20), font=_font(13))
    return img


def _ascii(text: str) -> str:
    """Pillow's built-in font has no arrows."""
    return text.replace("←", "<-").replace("→", "->")


def _tile(p: Performer, words: str, width: int, height: int) -> Image.Image:
    img: Image.Image = p.camera.shoot(p.controller.body.data.qpos)
    draw = ImageDraw.Draw(img)
    draw.text((5, 4), p.name, fill=(0, 0, 0), font=_font(14))
    lines = [words]
    if p.note:
        lines.append(p.note)
    draw.text((5, height - 16 * len(lines) - 2), _ascii("\n".join(lines)), fill=(40, 40, 40),
              font=_font(11))
    return img


def render(phrase_ref: str | Path, out: Path, gif: Path | None, platforms: Sequence[str],
           width: int = 320, height: int = 240, fps: float = 15.0) -> int:
    """Render the phrase; returns the number of frames written to each file."""
    import imageio_ffmpeg

    from kinesphere.clients.orders.phrases import load_phrase
    from kinesphere.words import drive_words, part_words

    if width % 2 or height % 2 or width < 64 or height < 64:
        raise KinesphereError("malformed", "--width and --height must be even and >= 64")
    if not 1 <= fps <= 60:
        raise KinesphereError("malformed", f"--fps must be 1..60, got {fps}")
    phrase = load_phrase(phrase_ref)
    performers = _performers(platforms, phrase, width, height)
    total_w = width * len(performers)
    size = (total_w, height + CAPTION_H)
    frames = math.ceil(phrase.duration * fps)
    starts = np.cumsum([0.0] + [s.duration for s in phrase.steps])
    writer = imageio_ffmpeg.write_frames(str(out), size, fps=fps, macro_block_size=1,
                                         quality=7)
    writer.send(None)
    gif_frames: list[Image.Image] = []
    step_i = -1
    try:
        for k in range(frames):
            t = k / fps
            i = int(np.searchsorted(starts, t, side="right") - 1)
            if i != step_i:
                step_i = i
                for p in performers:
                    _start(p, phrase.steps[i])
            for p in performers:
                while p.controller.time < t - 1e-9:
                    p.controller.step()
            step = phrase.steps[step_i]
            heading = f"{phrase.name} · step {step_i + 1}/{len(phrase.steps)}"
            heading += f": {step.note}" if step.note else ""
            canvas = Image.new("RGB", size, (255, 255, 255))
            canvas.paste(_caption(f"{heading}\nt = {t:4.1f} s", total_w), (0, 0))
            for j, p in enumerate(performers):
                words = " + ".join([*(part_words(x, p.names) for x in step.parts),
                                    *([drive_words(step.drive)] if step.drive else [])])
                canvas.paste(_tile(p, words, width, height), (j * width, CAPTION_H))
            writer.send(np.ascontiguousarray(np.asarray(canvas)))
            if gif is not None:
                gif_frames.append(canvas.quantize(colors=128))
    finally:
        writer.close()
        for p in performers:
            p.camera.close()
    if gif is not None and gif_frames:
        gif_frames[0].save(gif, save_all=True, append_images=gif_frames[1:],
                           duration=round(1000 / fps), loop=0, optimize=False)
    return frames
