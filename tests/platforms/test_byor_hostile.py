"""``platform new`` with a hostile package: nothing read from outside the package, nothing
written more readable than its source, names checked, sizes, counts and time bounded, NaN and
cycles refused, and every refusal one error line with nothing left behind."""

from __future__ import annotations

import os
import stat
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

from kinesphere.cli import main
from kinesphere.eurdf import MAX_LINKS, load_eurdf
from kinesphere.platforms.platform import load_platform
from kinesphere.platforms.scaffold import new_platform

LINK = """<link name="{name}"><inertial><mass value="1"/>
<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>{geometry}</link>"""
JOINT = """<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>
<origin xyz="{xyz}"/><axis xyz="0 1 0"/>
<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>"""
BOX = '<collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision>'


def mesh(filename: str) -> str:
    return (f'<visual><geometry><mesh filename="{filename}"/></geometry></visual>'
            f'<collision><geometry><mesh filename="{filename}"/></geometry></collision>')


def arm(links: int = 3, geometry: str = BOX, xyz: str = "0 0 0.2", first: str = "") -> str:
    """A chain of ``links`` links on revolute joints (the first link's geometry ``first``)."""
    parts = [LINK.format(name="l0", geometry=first or geometry)]
    for i in range(1, links):
        parts.append(LINK.format(name=f"l{i}", geometry=geometry))
        parts.append(JOINT.format(name=f"j{i}", parent=f"l{i - 1}", child=f"l{i}", xyz=xyz))
    return '<robot name="hostile">' + "".join(parts) + "</robot>"


def binary_stl(path: Path, faces: int, triangle: tuple[float, ...] | None = None) -> None:
    """A binary STL of ``faces`` copies of one triangle (a tetrahedron's faces when 4)."""
    tetra = [(0, 0, 0), (0.1, 0, 0), (0, 0.1, 0), (0, 0, 0.1)]
    tris = [(tetra[a], tetra[b], tetra[c]) for a, b, c in ((0, 2, 1), (0, 1, 3), (0, 3, 2),
                                                            (1, 2, 3))]
    with path.open("wb") as fh:
        fh.write(b"\0" * 80 + struct.pack("<I", faces))
        for k in range(faces):
            tri = tris[k % 4] if triangle is None else (triangle[:3], triangle[3:6],
                                                       triangle[6:9])
            fh.write(struct.pack("<12fH", 0, 0, 0, *(c for v in tri for c in v), 0))


def package(tmp: Path, urdf_text: str, name: str = "robot.urdf") -> Path:
    pkg = tmp / "pkg"
    (pkg / "meshes").mkdir(parents=True, exist_ok=True)
    urdf = pkg / name
    urdf.write_text(urdf_text)
    return urdf


def refused(capsys: pytest.CaptureFixture[str], args: list[str], words: str) -> str:
    """The command exits 2 with one 'error:' line holding ``words``, and no traceback."""
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and words in lines[0], err
    return lines[0]


def nothing_in(folder: Path) -> None:
    """No platform folder, no hidden work folder: nothing half-written."""
    assert not folder.exists() or list(folder.iterdir()) == [], list(folder.iterdir())


def new_refused(capsys: pytest.CaptureFixture[str], name: str, urdf: Path, out: Path,
                words: str) -> None:
    """``platform new NAME --urdf URDF --dir OUT`` is :func:`refused` with ``words`` and
    leaves :func:`nothing_in` OUT."""
    refused(capsys, ["platform", "new", name, "--urdf", str(urdf), "--dir", str(out)], words)
    nothing_in(out)


def test_a_mesh_symlinked_out_of_the_package_is_never_read(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    secret = tmp_path / "secret"
    secret.write_text("root:SECRET-HASH:19000:0:99999:7:::\n")
    secret.chmod(0o600)
    urdf = package(tmp_path, arm(geometry=mesh("meshes/link.stl")))
    (urdf.parent / "meshes" / "link.stl").symlink_to(secret)
    new_refused(capsys, "bot", urdf, tmp_path / "out", "outside its package")
    # a symlinked folder leads out just the same
    (urdf.parent / "meshes" / "link.stl").unlink()
    (urdf.parent / "meshes").rmdir()
    (tmp_path / "elsewhere").mkdir()
    binary_stl(tmp_path / "elsewhere" / "link.stl", 4)
    (urdf.parent / "meshes").symlink_to(tmp_path / "elsewhere")
    new_refused(capsys, "bot", urdf, tmp_path / "out", "outside its package")


def test_no_file_is_written_more_readable_than_its_source(tmp_path: Path) -> None:
    urdf = package(tmp_path, arm(geometry=mesh("meshes/link.stl")))
    binary_stl(urdf.parent / "meshes" / "link.stl", 4)
    (urdf.parent / "meshes" / "link.stl").chmod(0o600)
    urdf.chmod(0o600)
    made = new_platform("private", urdf, tmp_path / "out")
    files = [p for p in made.folder.rglob("*") if p.is_file()]
    assert {p.suffix for p in files} >= {".eurdf", ".toml", ".stl"}
    for p in files:
        assert stat.S_IMODE(p.stat().st_mode) & 0o077 == 0, (p, oct(p.stat().st_mode))
    assert stat.S_IMODE(made.folder.stat().st_mode) & 0o077 == 0


def ascii_stl(path: Path, side: float) -> None:
    """An ASCII STL of a tetrahedron with sides ``side`` m (MuJoCo reads none: converted)."""
    tetra = [(0.0, 0.0, 0.0), (side, 0.0, 0.0), (0.0, side, 0.0), (0.0, 0.0, side)]
    lines = ["solid tetra"]
    for face in ((0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)):
        lines += ["facet normal 0 0 0", "outer loop",
                  *(f"vertex {x} {y} {z}" for x, y, z in (tetra[i] for i in face)),
                  "endloop", "endfacet"]
    path.write_text("\n".join([*lines, "endsolid tetra"]) + "\n")


def test_a_mesh_changed_between_two_imports_in_one_process_is_read_again(
    tmp_path: Path
) -> None:
    """A process converts a mesh file once for the robots that share it, unless it changed."""
    urdf = package(tmp_path, arm(geometry=mesh("meshes/link.stl")))
    ascii_stl(urdf.parent / "meshes" / "link.stl", 0.1)

    def written(name: str) -> bytes:
        made = new_platform(name, urdf, tmp_path / "out")
        assert made.meshes.converted == 1 and made.meshes.hulls == 0
        (stl,) = (made.folder / "meshes").iterdir()
        return stl.read_bytes()

    def side(stl: bytes) -> float:
        (faces,) = struct.unpack("<I", stl[80:84])
        return max(float(c) for k in range(faces)
                   for c in struct.unpack("<12fH", stl[84 + 50 * k: 134 + 50 * k])[3:12])

    first = written("first")
    assert side(first) == pytest.approx(0.1)
    assert written("again") == first
    ascii_stl(urdf.parent / "meshes" / "link.stl", 0.25)
    assert side(written("changed")) == pytest.approx(0.25)


def test_names_from_the_package_cannot_break_the_files_written(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]
                                                               ) -> None:
    out = tmp_path / "out"
    dashes = package(tmp_path, arm(), "my--robot.urdf")
    assert main(["platform", "new", "dashes", "--urdf", str(dashes), "--dir", str(out)]) == 0
    assert load_eurdf(out / "dashes" / "dashes.eurdf").name == "dashes"
    quote = package(tmp_path, arm(), 'my"robot\n.urdf')
    assert main(["platform", "new", "quote", "--urdf", str(quote), "--dir", str(out)]) == 0
    assert load_platform(str(out / "quote")).title == 'quote (brought from my"robot\n.urdf)'
    capsys.readouterr()
    for bad in ("my--robot", 'a"b', "9x", "UPPER", "a" * 40, "a__b", "a-"):
        refused(capsys, ["platform", "new", bad, "--urdf", str(dashes), "--dir", str(out)],
                "platform name")
    assert sorted(p.name for p in out.iterdir()) == ["dashes", "quote"]


def _new_in_a_process(urdf: Path, out: Path) -> tuple[subprocess.CompletedProcess[str], float]:
    start = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "kinesphere.cli", "platform", "new", "big",
                           "--urdf", str(urdf), "--dir", str(out)],
                          capture_output=True, text=True, timeout=90)
    return done, time.monotonic() - start


def test_links_and_joints_are_bounded_with_a_clear_error_at_once(tmp_path: Path) -> None:
    chain = package(tmp_path, arm(MAX_LINKS + 1, xyz="0 0 0.01"), "chain.urdf")
    root = LINK.format(name="hub", geometry="")
    spokes = "".join(
        LINK.format(name=f"s{i}", geometry="")
        + JOINT.format(name=f"k{i}", parent="hub", child=f"s{i}", xyz="0 0 0.1")
        for i in range(10_000))
    star = package(tmp_path, f'<robot name="star">{root}{spokes}</robot>', "star.urdf")
    for urdf in (chain, star):
        done, seconds = _new_in_a_process(urdf, tmp_path / "out")
        assert done.returncode == 2, done.stderr[-500:]
        assert f"at most {MAX_LINKS}" in done.stderr and "Traceback" not in done.stderr
        assert seconds < 60, seconds
    nothing_in(tmp_path / "out")


def test_a_run_past_its_time_bound_stops_with_a_clear_error(tmp_path: Path) -> None:
    urdf = package(tmp_path, arm())
    with pytest.raises(Exception, match="took more than"):
        new_platform("slow", urdf, tmp_path / "out", time_limit=0.0)
    nothing_in(tmp_path / "out")


@pytest.mark.parametrize("where", [
    'xyz="nan 0 0.2"', 'xyz="0 0 inf"', 'xyz="0 0 0.2" rpy="0 NaN 0"'])
def test_nan_anywhere_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                 where: str) -> None:
    urdf = package(tmp_path, arm().replace('xyz="0 0 0.2"', where, 1))
    new_refused(capsys, "nan", urdf, tmp_path / "out", "not a finite number")


def test_nan_in_an_inertia_or_a_shape_is_refused(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    for text in (arm().replace('ixx="0.01"', 'ixx="nan"', 1),
                 arm().replace('size="0.1 0.1 0.1"', 'size="0.1 nan 0.1"', 1)):
        new_refused(capsys, "nan", package(tmp_path, text), tmp_path / "out",
                    "not a finite number")


@pytest.mark.parametrize(("faces", "triangle", "words"), [
    (200_001, None, "200001 faces"),  # past MuJoCo's limit for an STL
    (1, (0, 0, 0, 1, 0, 0, 0, 1, 0), "at least 4"),  # three vertices: no volume
])
def test_an_stl_mujoco_cannot_read_is_a_clear_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], faces: int,
    triangle: tuple[float, ...] | None, words: str
) -> None:
    urdf = package(tmp_path, arm(geometry=mesh("meshes/part.stl")))
    binary_stl(urdf.parent / "meshes" / "part.stl", faces, triangle)
    new_refused(capsys, "part", urdf, tmp_path / "out", words)


def test_a_kinematic_cycle_is_a_clear_error(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    links = "".join(LINK.format(name=n, geometry=BOX) for n in ("a", "b", "c"))
    joints = (JOINT.format(name="ab", parent="a", child="b", xyz="0 0 0.1")
              + JOINT.format(name="bc", parent="b", child="c", xyz="0 0 0.1")
              + JOINT.format(name="ca", parent="c", child="a", xyz="0 0 0.1"))
    urdf = package(tmp_path, f'<robot name="loop">{links}{joints}</robot>')
    new_refused(capsys, "loop", urdf, tmp_path / "out", "cycle")


def test_a_missing_urdf_creates_nothing(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    refused(capsys, ["platform", "new", "ghost", "--urdf", str(tmp_path / "none.urdf"),
                     "--dir", str(out)], "not found")
    assert not out.exists()


def test_a_failed_replacement_keeps_the_old_platform_whole(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = package(tmp_path, arm())
    out = tmp_path / "out"
    assert main(["platform", "new", "keep", "--urdf", str(good), "--dir", str(out)]) == 0
    before = {p.name: p.read_bytes() for p in (out / "keep").iterdir() if p.is_file()}
    bad = package(tmp_path, arm().replace('xyz="0 0 0.2"', 'xyz="nan 0 0"', 1), "bad.urdf")
    refused(capsys, ["platform", "new", "keep", "--urdf", str(bad), "--dir", str(out),
                     "--force"], "not a finite number")
    after = {p.name: p.read_bytes() for p in (out / "keep").iterdir() if p.is_file()}
    assert after == before
    assert [p.name for p in out.iterdir()] == ["keep"]
    assert os.listdir(out / "keep") and load_platform(str(out / "keep")).name == "keep"
