"""The URDF records every role reads: equal to yourdfpy's own parse (the reader of record),
kept on disk by content (a changed text or reader is a new entry; damage, the off switch
and the bound are honoured), and a process that loads a description read before does not
import yourdfpy, trimesh or SciPy."""

from __future__ import annotations

import functools
import io
import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
import yourdfpy

from kinesphere import urdf_tree
from kinesphere.eurdf import load_eurdf
from kinesphere.filecache import CACHE_ENV, OFF, FileCache
from kinesphere.platforms.platform import load_platform, platform_names
from kinesphere.urdf_tree import UrdfShape, read_urdf
from support.byor import MINITAUR, PANDA, pybullet_data, robot_data
from support.paths import ROOT, TOY_EURDF


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "cache"
    monkeypatch.setenv(CACHE_ENV, str(folder))
    return folder / "urdf"


def _same(ours: Any, theirs: Any) -> bool:
    if ours is None or theirs is None:
        return ours is None and theirs is None
    return bool(np.allclose(np.asarray(ours, float), np.asarray(theirs, float)))


def _same_shape(ours: UrdfShape, theirs: Any) -> None:
    assert ours.name == theirs.name and _same(ours.origin, theirs.origin)
    g, h = ours.geometry, theirs.geometry
    assert (g is None) == (h is None)
    if g is None:
        return
    assert (g.box is None) == (h.box is None) and (g.mesh is None) == (h.mesh is None)
    if g.box is not None:
        assert _same(g.box.size, h.box.size)
    if g.cylinder is not None:
        assert (g.cylinder.radius, g.cylinder.length) == (h.cylinder.radius, h.cylinder.length)
    if g.sphere is not None:
        assert g.sphere.radius == h.sphere.radius
    if g.mesh is not None:
        assert g.mesh.filename == h.mesh.filename and _same(g.mesh.scale, h.mesh.scale)
    theirs_material: Any = getattr(theirs, "material", None)
    assert (ours.material is None) == (theirs_material is None)
    if ours.material is not None:
        assert ours.material.name == theirs_material.name
        assert _same(ours.material.rgba,
                     None if theirs_material.color is None else theirs_material.color.rgba)


def _assert_as_yourdfpy(text: str) -> None:
    ours = read_urdf(text)
    theirs = yourdfpy.URDF.load(io.BytesIO(text.encode()), load_meshes=False,
                                build_scene_graph=False, build_collision_scene_graph=False)
    assert ours.robot.name == theirs.robot.name
    assert list(ours.link_map) == [link.name for link in theirs.robot.links]
    assert list(ours.joint_map) == [j.name for j in theirs.robot.joints]
    for link, their_link in zip(ours.robot.links, theirs.robot.links, strict=True):
        i, k = link.inertial, their_link.inertial
        assert (i is None) == (k is None)
        if i is not None:
            assert _same(i.origin, k.origin) and _same(i.inertia, k.inertia)
            assert i.mass == k.mass
        for mine, their in ((link.visuals, their_link.visuals),
                            (link.collisions, their_link.collisions)):
            assert len(mine) == len(their)
            for a, b in zip(mine, their, strict=True):
                _same_shape(a, b)
    for j, their_joint in zip(ours.robot.joints, theirs.robot.joints, strict=True):
        assert (j.type, j.parent, j.child) == (their_joint.type, their_joint.parent,
                                               their_joint.child)
        assert _same(j.origin, their_joint.origin) and _same(j.axis, their_joint.axis)
        lim, their_lim = j.limit, their_joint.limit
        assert (lim is None) == (their_lim is None)
        if lim is not None:
            assert (lim.lower, lim.upper, lim.velocity, lim.effort) == (
                their_lim.lower, their_lim.upper, their_lim.velocity, their_lim.effort)
        mim, their_mim = j.mimic, their_joint.mimic
        assert (mim is None) == (their_mim is None)
        if mim is not None:
            assert (mim.joint, mim.multiplier, mim.offset) == (
                their_mim.joint, their_mim.multiplier, their_mim.offset)
    assert [(m.name, None if m.rgba is None else m.rgba.tolist()) for m in ours.robot.materials] \
        == [(m.name, None if m.color is None else list(m.color.rgba))
            for m in theirs.robot.materials]


SOURCES: dict[str, Callable[[], Path | None]] = {
    **{name: functools.partial(lambda n: load_platform(n).eurdf.path, name)
       for name in platform_names()},
    "panda": lambda: robot_data() / PANDA,
    "minitaur (meshes, scales, colours)": lambda: pybullet_data() / MINITAUR,
    "r2d2 (cylinders, spheres)": lambda: pybullet_data() / "r2d2.urdf",
}


@pytest.mark.parametrize("source", sorted(SOURCES))
def test_records_equal_yourdfpy_read_and_cached(source: str, cache: Path) -> None:
    path = SOURCES[source]()
    assert path is not None
    text = path.read_text(encoding="utf-8")
    _assert_as_yourdfpy(text)  # a fresh read
    (entry,) = cache.iterdir()
    assert urdf_tree._unsealed(entry.read_bytes()) is not None, "whole and well formed"
    _assert_as_yourdfpy(text)  # the same, decoded from the cache
    assert read_urdf(text) == read_urdf(text)


def test_mimics_materials_and_scales_survive_the_cache(cache: Path) -> None:
    text = TOY_EURDF.read_text().replace(
        "</robot>",
        '<material name="teal"><color rgba="0 0.5 0.5 1"/></material>'
        '<link name="extra"><visual><geometry><mesh filename="m.stl" scale="0.001"/>'
        '</geometry><material name="teal"/></visual></link>'
        '<joint name="extra_joint" type="revolute"><parent link="tip"/><child link="extra"/>'
        '<limit lower="-1" upper="1" velocity="2" effort="3"/>'
        '<mimic joint="elbow" multiplier="-2" offset="0.5"/></joint></robot>')
    _assert_as_yourdfpy(text)
    _assert_as_yourdfpy(text)


def test_a_changed_text_is_read_again(cache: Path, tmp_path: Path) -> None:
    path = tmp_path / "toy.eurdf"
    text = TOY_EURDF.read_text()
    path.write_text(text)
    assert load_eurdf(path).limits["elbow"].lower == -2.0
    elbow = '<joint name="elbow"'
    start = text.index(elbow)
    path.write_text(text[:start] + text[start:].replace('lower="-2"', 'lower="-1.25"', 1))
    assert load_eurdf(path).limits["elbow"].lower == -1.25
    assert load_eurdf(path).urdf != load_eurdf(TOY_EURDF).urdf
    assert len(list(cache.iterdir())) == 2


def test_a_changed_reader_is_a_new_entry(cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    text = TOY_EURDF.read_text()
    read_urdf(text)
    monkeypatch.setattr(urdf_tree, "_reader", lambda: (b"another reader",))
    read_urdf(text)
    assert len(list(cache.iterdir())) == 2


def test_a_damaged_entry_is_read_again(cache: Path) -> None:
    text = TOY_EURDF.read_text()
    read_urdf(text)
    (entry,) = cache.iterdir()
    entry.write_bytes(b"\x93 not a tree")
    assert list(read_urdf(text).joint_map)[:2] == ["yaw", "elbow"]
    assert entry.read_bytes() != b"\x93 not a tree"  # rewritten whole


def test_off_writes_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(CACHE_ENV, OFF)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("HOME", str(tmp_path))
    assert load_eurdf(TOY_EURDF).C == ("c_1",)
    assert list(tmp_path.iterdir()) == []


def test_the_least_recently_used_go_past_the_bounds(cache: Path) -> None:
    small = FileCache("urdf", max_entries=3, max_bytes=10, max_total=25)
    keys = [f"{i:064x}" for i in range(5)]
    for i, key in enumerate(keys):
        small.put(key, b"x")
        os.utime(cache / key, (1000 + i, 1000 + i))
        if i == 2:
            assert small.get(keys[0]) == b"x"  # used: now the newest
    assert sorted(p.name for p in cache.iterdir()) == sorted([keys[0], keys[3], keys[4]])
    for key in keys[1:4]:
        small.put(key, b"y" * 10)
    # three entries of 10 bytes are more than 25 in all: the oldest of them went too
    assert sorted(p.name for p in cache.iterdir()) == sorted(keys[2:4])
    small.put(keys[4], b"v" * 11)  # larger than an entry may be
    assert small.get(keys[4]) is None and not (cache / keys[4]).exists()
    assert small.get("../escape") is None


@pytest.mark.processes
def test_a_warm_load_imports_no_yourdfpy(cache: Path) -> None:
    """What every agent, databank and view start skips: yourdfpy and what it imports."""
    code = ("import sys, json; from kinesphere.platforms.mjcf import platform_model; "
            "platform_model('nao'); print(json.dumps([m for m in ('yourdfpy', 'trimesh', "
            "'scipy', 'networkx') if m in sys.modules]))")
    env = {**os.environ, "MUJOCO_GL": "egl"}
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           check=True, env=env, cwd=ROOT) for _ in range(2)]
    assert json.loads(runs[0].stdout) == ["yourdfpy", "trimesh", "scipy", "networkx"]  # cold
    assert json.loads(runs[1].stdout) == []


def _with_joints(robot: urdf_tree.UrdfRobot, **changes: Any) -> urdf_tree.UrdfRobot:
    """``robot`` with every limited joint's limit (or, given ``origin``, every joint's origin)
    changed."""
    def changed(j: urdf_tree.UrdfJoint) -> urdf_tree.UrdfJoint:
        if "origin" in changes:
            return msgspec.structs.replace(j, origin=changes["origin"])
        if j.limit is None:
            return j
        return msgspec.structs.replace(j, limit=msgspec.structs.replace(j.limit, **changes))
    return msgspec.structs.replace(robot, joints=tuple(map(changed, robot.joints)))


def test_an_entry_is_used_only_whole_and_well_formed(cache: Path) -> None:
    """The joint limits an agent keeps to come through here: an entry changed on disk, or
    one sealed right but not of yourdfpy's shapes (a run that broke), is never used — the
    text is read again and the entry written anew, never a wrong limit nor a crash later."""
    text = TOY_EURDF.read_text()
    truth = read_urdf(text)
    (entry,) = cache.iterdir()
    sealed = entry.read_bytes()
    robot = truth.robot
    wide = urdf_tree._encoded(_with_joints(robot, lower=-100.0, upper=100.0))
    bad = {
        "a limit changed on disk": sealed[:32] + wide,
        "cut short": sealed[:-7],
        "an origin of two numbers": urdf_tree._sealed(
            _with_joints(robot, origin=np.array([1.0, 2.0]))),
        "a limit upside down": urdf_tree._sealed(_with_joints(robot, lower=1.0, upper=-1.0)),
        "a limit not finite": urdf_tree._sealed(_with_joints(robot, upper=float("inf"))),
    }
    for what, data in bad.items():
        entry.write_bytes(data)
        assert read_urdf(text) == truth, what
        assert entry.read_bytes() == sealed, f"{what}: written anew"
    assert load_eurdf(TOY_EURDF).limits == load_eurdf(TOY_EURDF).limits


def test_a_cache_others_may_write_to_is_not_used(cache: Path) -> None:
    """Entries in a folder another user may write to could be anyone's: none is read or
    written there."""
    cache.mkdir(parents=True)
    cache.chmod(0o777)
    text = TOY_EURDF.read_text()
    read_urdf(text)
    assert list(cache.iterdir()) == []
    cache.chmod(0o755)
    read_urdf(text)
    assert len(list(cache.iterdir())) == 1
