"""Bodies from the wire, hostile or brought: checked completely, built once, drawn in linear
time, meshes only from the message.

Before: ``<limit lower="abc">`` and ``<box size="1 1"/>`` crashed the view (ValueError,
TypeError), NaN radii and origins were drawn, a refused body was parsed again every frame
(251 warnings, 0 frames/s for every robot), a 250-link chain took 66 s (~n^4), and mesh
names were opened on the view's own machine (absolute, ``../``, ``file://``, relative to its
working directory) while a brought robot's meshes showed only inside its platform folder.
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

import pytest
import trimesh
import zenoh

from kinesphere import protocol as pr
from kinesphere import zconfig
from kinesphere.cli import main
from kinesphere.clients.view.app import FleetView
from kinesphere.clients.view.body import BodyGeometry
from kinesphere.clients.view.resolve import Bodies
from kinesphere.errors import KinesphereError
from kinesphere.eurdf import MAX_DEPTH, MAX_LINKS, load_eurdf, plain_urdf
from kinesphere.platforms.platform import load_platform
from kinesphere.services.databank.body import body_model
from support.byor import PANDA, robot_data
from support.hostile import BROKEN_NUMBERS, arm, model, nested
from support.network import OWN_KEYS, Hub
from support.paths import TOY
from support.wait import WAIT_S

if TYPE_CHECKING:
    from _typeshed import TraceFunction


@pytest.mark.parametrize("flaw", list(BROKEN_NUMBERS))
def test_a_malformed_number_or_shape_is_refused_by_name(flaw: str) -> None:
    with pytest.raises(KinesphereError) as err:
        BodyGeometry(model(BROKEN_NUMBERS[flaw]))
    assert err.value.code == "invalid_eurdf", err.value


def test_chains_past_the_depth_links_past_the_count_and_deep_xml_are_refused() -> None:
    assert len(BodyGeometry(model(arm(MAX_DEPTH))).frame_paths) == MAX_DEPTH
    for text, words in ((arm(MAX_DEPTH + 1), "joints below the root"),
                        (arm(MAX_LINKS + 1), f"at most {MAX_LINKS}"),
                        (nested(5000), "nested more than")):
        with pytest.raises(KinesphereError) as err:
            load_eurdf(text)
        assert err.value.code == "invalid_eurdf" and words in err.value.message
    with pytest.raises(KinesphereError) as err:  # the ROS 2 bridge's path: RecursionError
        plain_urdf(nested(5000))
    assert err.value.code == "invalid_eurdf"


def _lines(build: Callable[[], object]) -> int:
    """Python lines executed by ``build()``: the work done, independent of the machine."""
    count = 0

    def tracer(frame: FrameType, event: str, arg: object) -> TraceFunction:
        nonlocal count
        if event == "line":
            count += 1
        return tracer

    sys.settrace(tracer)
    try:
        build()
    finally:
        sys.settrace(None)
    return count


def _arm_geometry(links: int) -> BodyGeometry:
    return BodyGeometry(model(arm(links)))


def test_building_a_body_costs_work_linear_in_its_links() -> None:
    """Counted in executed lines, so load does not matter: doubling the chain at most a bit
    over doubles the work (the old scene-graph path multiplied whole chains per shape, and
    numpy's chain-order search is cubic Python: ~16x per doubling)."""
    small, mid, large = (_lines(partial(_arm_geometry, n)) for n in (8, 16, 32))
    assert mid / small < 2.5 and large / mid < 2.5, (small, mid, large)


def test_a_refused_body_is_parsed_once_and_logged_once(caplog: pytest.LogCaptureFixture
                                                       ) -> None:
    bodies = Bodies()
    bad = BROKEN_NUMBERS["cylinder radius nan"]
    for i in range(100):
        with pytest.raises(KinesphereError) as err:
            bodies.body(model(bad, platform=f"name-{i % 7}"))  # new platform names too
        assert err.value.code == "invalid_eurdf" and "refused" in err.value.message
    good = bodies.body(model(arm(3), platform="a"))
    assert bodies.body(model(arm(3), platform="b")).platform == "b" and good.platform == "a"
    forged = model(bad, platform="c")  # a refused body claiming a good one's version
    forged = pr.BodyModel(platform="c", eurdf=forged.eurdf, base_kind="fixed", neutral={},
                          version=model(arm(3)).version)
    with pytest.raises(KinesphereError):
        bodies.body(forged)
    assert bodies.built == 2  # the refused one, the good one: once each
    refused = [r for r in caplog.records if "refused" in r.getMessage()]
    assert len(refused) == 1


class OpenedFiles:
    """Every file the interpreter opens while :attr:`on` (an audit hook: hooks cannot be
    removed, so this one stays, switched off)."""

    def __init__(self) -> None:
        self.on = False
        self.paths: list[str] = []
        sys.addaudithook(self._hook)

    def _hook(self, event: str, args: tuple[object, ...]) -> None:
        if self.on and event == "open" and isinstance(args[0], (str, bytes, os.PathLike)):
            self.paths.append(os.fsdecode(args[0]))


@pytest.fixture(scope="module")
def opened() -> OpenedFiles:
    return OpenedFiles()


def _stl(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=(0.1, 0.2, 0.3)).export(path)
    return path


def test_the_view_never_opens_a_file_a_body_names(tmp_path: Path, opened: OpenedFiles,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    secret = _stl(tmp_path / "secret" / "key.stl")
    here = tmp_path / "work" / "deep"
    _stl(here / "meshes" / "local.stl")
    here.mkdir(parents=True, exist_ok=True)
    monkeypatch.chdir(here)
    names = [str(secret), f"file://{secret}", "../../secret/key.stl", "meshes/local.stl",
             "package://secret/key.stl"]
    geometry = "".join(f'<mesh filename="{n}"/>' for n in names[:1])
    text = arm(len(names), geometry=geometry)
    for i, name in enumerate(names):  # one name per link
        text = text.replace(f'<link name="l{i}"><visual><origin xyz="0 0 0.1"/><geometry>'
                            f'{geometry}', f'<link name="l{i}"><visual><origin xyz="0 0 0.1"/>'
                            f'<geometry><mesh filename="{name}"/>', 1)
    opened.on = True
    try:
        body = BodyGeometry(model(text))
    finally:
        opened.on = False
    touched = [p for p in opened.paths if "secret" in p or "local.stl" in p]
    assert touched == [], touched
    assert sorted(body.missing) == sorted(names)
    assert len(body.shapes) == 1  # the base's box; no mesh drawn
    carried = pr.BodyModel(platform="hostile", eurdf=text, base_kind="fixed", neutral={},
                           version="v", meshes={"meshes/local.stl": secret.read_bytes()})
    drawn = BodyGeometry(carried)  # what the message carries is drawn, by the name the text uses
    assert len(drawn.shapes) == 2 and "meshes/local.stl" not in drawn.missing


def _toy_with_meshes(folder: Path) -> Path:
    """The toy arm with mesh visuals: its own mesh, and names pointing out of the folder."""
    shutil.copytree(TOY, folder)
    _stl(folder / "meshes" / "upper.stl")
    outside = _stl(folder.parent / "outside.stl")
    (folder / "meshes" / "link.stl").symlink_to(outside)
    (folder / "meshes" / "notes.txt").write_text("not a mesh")
    text = (folder / "toyarm.eurdf").read_text()
    visuals = {"upper": "meshes/upper.stl", "lower": "../outside.stl", "hand": str(outside),
               "tip": "meshes/link.stl", "tail": "meshes/notes.txt"}
    for link, name in visuals.items():
        text = text.replace(f'<link name="{link}">', f'<link name="{link}"><visual><geometry>'
                            f'<mesh filename="{name}"/></geometry></visual>', 1)
    text = text.replace('<link name="tip"/>', '<link name="tip"><visual><geometry><mesh '
                        'filename="meshes/link.stl"/></geometry></visual></link>')
    (folder / "toyarm.eurdf").write_text(text)
    return folder


def test_the_databank_sends_a_platforms_own_meshes_and_nothing_outside(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    folder = _toy_with_meshes(tmp_path / "toyarm")
    body = body_model(load_platform(str(folder)))
    assert set(body.meshes) == {"meshes/upper.stl"}
    assert body.meshes["meshes/upper.stl"] == (folder / "meshes" / "upper.stl").read_bytes()
    assert "4 mesh file(s) not sent" in caplog.text
    again = pr.decode(pr.encode(body), pr.BodyModel)  # over the wire, bounded
    assert again.meshes == body.meshes


@pytest.fixture(scope="module")
def panda(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    root = tmp_path_factory.mktemp("brought")
    assert main(["platform", "new", "panda", "--urdf", str(robot_data() / PANDA),
                 "--dir", str(root)]) == 0
    yield root / "panda"


def test_a_brought_robot_shows_its_meshes_wherever_the_view_runs(
    panda: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, opened: OpenedFiles
) -> None:
    """Before: 0 of its mesh shapes outside the platform folder (the view opened the mesh
    names relative to its working directory)."""
    plat = load_platform(str(panda))
    visuals = [v for link in plat.eurdf.urdf.robot.links for v in link.visuals
               if v.geometry is not None and v.geometry.mesh is not None]
    wire = pr.encode(body_model(plat))
    assert len(wire) <= pr.MAX_BODY_PAYLOAD
    monkeypatch.chdir(tmp_path)  # anywhere but the platform folder
    opened.on = True
    try:
        body = BodyGeometry(pr.decode(wire, pr.BodyModel))
    finally:
        opened.on = False
    assert body.missing == [] and visuals
    assert len(body.shapes) >= len(visuals)
    assert not [p for p in opened.paths if str(panda) in p]


def test_a_body_too_large_for_the_wire_is_refused_unread() -> None:
    big = pr.BodyModel(platform="x", eurdf=arm(2), base_kind="fixed", neutral={}, version="v",
                       meshes={f"m{i}.stl": b"\0" * pr.MAX_MESH_BYTES for i in range(5)})
    with pytest.raises(KinesphereError) as err:
        pr.decode(pr.encode(big), pr.BodyModel)
    assert err.value.code == "malformed" and "exceeds" in err.value.message


logging.getLogger("trimesh").setLevel(logging.ERROR)


def test_the_view_keeps_drawing_every_robot_beside_a_refused_body(
    hub: Hub, caplog: pytest.LogCaptureFixture
) -> None:
    """A forged databank answer for one platform: that robot is listed with the reason, the
    others are drawn, and the body is parsed once however many frames and robots ask."""
    keys = OWN_KEYS
    youbot = body_model(load_platform("youbot"))
    bodies = {"youbot": youbot, "hostile": model(BROKEN_NUMBERS["limit lower abc"], "hostile")}

    def answer(query: zenoh.Query) -> None:
        with query:
            platform = str(query.key_expr).split("/")[-2]
            if platform in bodies:
                query.reply(query.key_expr, pr.encode(bodies[platform]))

    with zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as robots:
        queryable = hub.session.declare_queryable(keys.body("*"), answer, complete=True)
        tokens = []
        view = FleetView(hub.session, keys, port=zconfig.free_port())
        try:
            robot_ids = {"good-1": "youbot", **{f"bad-{i}": "hostile" for i in range(5)}}
            for rid in robot_ids:
                tokens.append(robots.liveliness().declare_token(keys.alive_robot(rid)))
            names = list(youbot.neutral) or ["x"]
            deadline = time.monotonic() + WAIT_S
            frames = 0
            while time.monotonic() < deadline:
                for rid, platform in robot_ids.items():
                    joints = names if platform == "youbot" else []
                    robots.put(keys.state(rid), pr.encode(pr.RobotState(
                        robot_id=rid, platform=platform, seq=frames, stamp_ns=time.time_ns(),
                        joint_names=joints, q=[0.0] * len(joints), qd=[],
                        base_pose=[0.0, 0.0, 0.0], status="idle", last_command_seq=-1)))
                view.frame()
                frames += 1
                if "good-1" in view.drawings and frames > 60 and \
                        "refused" in view._panel_text:
                    break
                time.sleep(1 / 30)
            assert "good-1" in view.drawings, view._panel_text
            assert not any(r.startswith("bad") for r in view.drawings)
            assert view._panel_text.count("body of hostile refused") == 5
            assert view.databank.built.built == 2
        finally:
            view.close()
            zconfig.undeclare(queryable, *tokens)
    assert sum("refused" in r.getMessage() for r in caplog.records) == 1
