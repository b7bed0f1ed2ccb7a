"""``kinesphere film PHRASE``: a movement phrase performed by every body side by side, on video.

The paper's raters watched robots perform movement phrases; a film makes that evaluation
repeatable. Each platform is a real agent controller (MuJoCo model, Ruckig trajectories, the
same base controllers) stepped in robot time, its targets answered by its real ECL in
process, exactly as the agent would get them from the databank. Frames are MuJoCo off-screen
renders (``MUJOCO_GL=egl``) with the ECL's camera, composed side by side with a caption of
the current command in words, and written as MP4 (ffmpeg from imageio-ffmpeg) and GIF.

A Labanotation score (``film SCORE.json``) is filmed the same way: each body performs the parts
it has (:mod:`kinesphere.casting`), each keyframe reached at the score's time where the body's
limits allow (the agent's timed retarget), a mobile base turning to the score's facing; the
caption is the keyframe's notation, the tile says what the body does not perform.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Sequence
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
    casting: Any = None
    """A score's casting on this body (None for a phrase)."""
    start_yaw: float = 0.0


def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=size)
    except TypeError:
        return ImageFont.load_default()


@dataclass(frozen=True)
class Cue:
    """From ``at`` seconds on, every body goes to its next target (``start``); the caption
    says ``heading``, each tile ``words(performer)``."""

    at: float
    heading: str
    start: Callable[[Performer], None]
    words: Callable[[Performer], str]


def _performers(platforms: Sequence[str], targets_of: Callable[[str, Any], list[list[Any]]],
                width: int, height: int) -> list[Performer]:
    """A performer per platform, its camera framing the poses ``targets_of(platform, ecl)``
    (lists of parts) it will take."""
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
        for parts in targets_of(name, ecl):
            try:
                targets.append(pose_qpos(pm, _resolve(ecl, parts)))
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
    lines = [words] if words else []
    if p.note:
        lines.append(p.note)
    draw.text((5, height - 16 * len(lines) - 2), _ascii("\n".join(lines)), fill=(40, 40, 40),
              font=_font(11))
    return img


def _phrase_cues(phrase: Any) -> tuple[list[Cue], float]:
    """A phrase's steps as cues, and its duration."""
    from kinesphere.words import drive_words, part_words

    cues, at = [], 0.0
    for i, step in enumerate(phrase.steps):
        heading = f"{phrase.name} · step {i + 1}/{len(phrase.steps)}"
        heading += f": {step.note}" if step.note else ""

        def words(p: Performer, step: Any = step) -> str:
            return " + ".join([*(part_words(x, p.names) for x in step.parts),
                               *([drive_words(step.drive)] if step.drive else [])])

        def start(p: Performer, step: Any = step) -> None:
            _start(p, step)

        cues.append(Cue(at, heading, start, words))
        at += step.duration
    return cues, at


UPBEAT_S: Final = 1.5
"""A score's first keyframe: the starting pose, reached before the score's clock starts."""
HOLD_S: Final = 1.0
"""The last keyframe held this long at the end of a score's film."""


def _score_cues(gesture: Any, speed: float) -> tuple[list[Cue], float]:
    """A gesture's keyframes as cues (each toward its keyframe's time), and the duration."""
    first = gesture.keyframes[0]
    due = [UPBEAT_S + (k.time_ms - first.time_ms) / 1e3 / speed for k in gesture.keyframes]
    cues = []
    for i, kf in enumerate(gesture.keyframes):
        at = 0.0 if i == 0 else due[i - 1]
        arrive = None if i == 0 else due[i] - at
        heading = (f"{gesture.name} · {kf.name} ({i + 1}/{len(gesture.keyframes)}, at "
                   f"{due[i] - UPBEAT_S:.1f} s)\n{kf.notation()}")
        def start(p: Performer, kf: Any = kf, arrive: float | None = arrive) -> None:
            _perform(p, kf, arrive)

        cues.append(Cue(at, heading, start, _nothing))
    return cues, due[-1] + HOLD_S


def _nothing(p: Performer) -> str:
    return ""  # the tile says what the body does not perform (its note)


def _perform(p: Performer, kf: Any, arrive: float | None) -> None:
    """One keyframe on one body as ``play`` sends it: its parts at once (the chains its ECL
    refuses left out), arriving ``arrive`` seconds from now, a mobile base turning."""
    casting = p.casting
    assert casting is not None
    ctrl, kept, lacking = p.controller, [], list[str]()
    for chain in casting.chains():
        try:
            _resolve(p.ecl, casting.parts(kf, chain))
            kept.extend(chain)
        except KinesphereError:
            lacking.extend(r.column for r in chain)
    p.note = "; ".join(_short(casting.skipped, lacking))
    if kept:
        ctrl.joints.retarget(_resolve(p.ecl, casting.parts(kf, kept)).joints, duration=arrive)
    if casting.turns and ctrl.base is not None:
        ctrl.base.turn_to(p.start_yaw + math.radians(kf.turn_deg), arrive)
    elif kf.turn_deg:
        p.note += ("; " if p.note else "") + "no turn (fixed base)"


def _short(skipped: dict[str, str], lacking: list[str]) -> list[str]:
    """What a body does not perform, in a tile's few words."""
    out = []
    if "head" in skipped:
        out.append("no head")
    if any(why.startswith("one arm") for why in skipped.values()):
        out.append("one arm")
    sides = dict.fromkeys(c.split()[0] for c in lacking)
    out += [f"cannot: {s if s == 'head' else s + ' arm'}" for s in sides]
    return out


SETTLE_MAX_S: Final = 20.0
"""Robot time a film runs past its phrase at most, for every body to come to rest."""
SETTLED_QD: Final = 0.01
"""Joint speed (rad/s or m/s) below which a body whose trajectories ended is at rest."""
REST_S: Final = 1.0
"""How long a film shows every body at rest before it ends."""


def settled(p: Performer) -> bool:
    """The body's trajectories are done and it no longer moves."""
    ctrl = p.controller
    return not ctrl.moving and max(map(abs, ctrl.qd()), default=0.0) < SETTLED_QD


def aside(path: Path) -> Path:
    """Where ``path`` is written until it is whole (renamed over it at the end; the suffix
    stays, as ffmpeg picks the format from it)."""
    return path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")


def render(phrase_ref: str | Path, out: Path, gif: Path | None, platforms: Sequence[str],
           width: int = 320, height: int = 240, fps: float = 15.0, gesture: str | None = None,
           speed: float = 1.0, on_cue: Callable[[float, str], None] | None = None) -> int:
    """Render the phrase, or one gesture of a score (``gesture``, default its first, its
    times divided by ``speed``), then every body until it is at rest (at most
    :data:`SETTLE_MAX_S`) and :data:`REST_S` more, so the film ends where the robots are left,
    still; returns the number of frames written to each file. The files are written aside and
    renamed when whole: an interrupted film leaves nothing behind. ``on_cue(t, heading)`` hears
    each cue as the bodies start it, every frame before ``t`` already sent to the encoder, and
    the phrase's end (heading "coming to rest"): the progress of a render that takes a while."""
    import imageio_ffmpeg

    from kinesphere.casting import cast
    from kinesphere.clients.orders import score_play
    from kinesphere.clients.orders.phrases import load_phrase

    if width % 2 or height % 2 or width < 64 or height < 64:
        raise KinesphereError("malformed", "--width and --height must be even and >= 64")
    if not 1 <= fps <= 60:
        raise KinesphereError("malformed", f"--fps must be 1..60, got {fps}")
    logging.getLogger("OpenGL").setLevel(logging.WARNING)  # PyOpenGL's "module loaded" INFO
    if not 0.01 <= speed <= 100:
        raise KinesphereError("malformed", f"--speed must be 0.01..100, got {speed:g}")
    if score_play.is_score(str(phrase_ref)):
        score = score_play.load(str(phrase_ref))
        g = score.gesture(gesture) if gesture else score.gestures[0]
        cues, duration = _score_cues(g, speed)

        def targets_of(name: str, ecl: Any) -> list[list[Any]]:
            c = cast(name, ecl.catalogue().vocabulary, ecl.platform.base.kind,
                     ecl.catalogue().sizes)
            return [c.parts(kf) for kf in g.keyframes]
    else:
        if gesture is not None:
            raise KinesphereError("malformed", "--gesture applies to a score (SCORE.json)")
        phrase = load_phrase(phrase_ref)
        cues, duration = _phrase_cues(phrase)

        def targets_of(name: str, ecl: Any) -> list[list[Any]]:
            return [list(step.parts) for step in phrase.steps]
    performers = _performers(platforms, targets_of, width, height)
    if score_play.is_score(str(phrase_ref)):
        for p in performers:
            cat = p.ecl.catalogue()
            p.casting = cast(p.name, cat.vocabulary, cat.base_kind, cat.sizes)
            p.start_yaw = p.controller.base_pose()[2] if p.controller.base is not None else 0.0
    total_w = width * len(performers)
    size = (total_w, height + CAPTION_H)
    frames = math.ceil(duration * fps)
    starts = [c.at for c in cues]
    partial = [aside(out), *([aside(gif)] if gif is not None else [])]
    writer = imageio_ffmpeg.write_frames(str(partial[0]), size, fps=fps, macro_block_size=1,
                                         quality=7)
    writer.send(None)
    gif_frames: list[Image.Image] = []
    cue_i = -1
    k = 0
    done = False
    rested_at: float | None = None
    try:
        while not done:
            t = k / fps
            if k < frames:
                i = int(np.searchsorted(starts, t, side="right") - 1)
                if i != cue_i:
                    cue_i = i
                    for p in performers:
                        cues[i].start(p)
                    if on_cue is not None:
                        on_cue(t, cues[i].heading)
            elif k == frames:
                if on_cue is not None:
                    on_cue(t, "coming to rest")
                for p in performers:  # the operator lets go: a drive stops, poses go on
                    if p.controller.base is not None and p.controller.base.driving:
                        p.controller.base.stop()
            for p in performers:
                while p.controller.time < t - 1e-9:
                    p.controller.step()
            cue = cues[cue_i]
            heading = cue.heading
            if k >= frames:
                rest = all(settled(p) for p in performers)
                rested_at = (t if rested_at is None else rested_at) if rest else None
                done = (rested_at is not None and t - rested_at >= REST_S - 1e-9
                        ) or t >= duration + SETTLE_MAX_S
                heading += " · every body at rest" if rest else " · coming to rest"
            canvas = Image.new("RGB", size, (255, 255, 255))
            canvas.paste(_caption(f"{heading}\nt = {t:4.1f} s"
                                  if "\n" not in heading else
                                  f"{heading}   t = {t:4.1f} s", total_w), (0, 0))
            for j, p in enumerate(performers):
                canvas.paste(_tile(p, cue.words(p), width, height), (j * width, CAPTION_H))
            writer.send(np.ascontiguousarray(np.asarray(canvas)))
            if gif is not None:
                gif_frames.append(canvas.quantize(colors=128))
            k += 1
        writer.close()
        if gif is not None and gif_frames:
            gif_frames[0].save(partial[1], save_all=True, append_images=gif_frames[1:],
                               duration=round(1000 / fps), loop=0, optimize=False)
            os.replace(partial[1], gif)
        os.replace(partial[0], out)
    finally:
        writer.close()
        for p in performers:
            p.camera.close()
        for path in partial:
            path.unlink(missing_ok=True)
    return k
