"""One rule for every command's Zenoh session: options, per-command defaults, ``--cfg``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import pytest
import zenoh

from kinesphere import zconfig as zc
from kinesphere.cli import build_parser
from kinesphere.cliargs import (
    AGENT,
    OPERATOR,
    QUERY,
    SERVICE,
    WATCHER,
    ZenohDefaults,
    add_zenoh_arguments,
)
from kinesphere.errors import KinesphereError

DEFAULT = zc.DEFAULT_ENDPOINT
ANY = zc.LOOPBACK_ANY_PORT
OTHER = "tcp/127.0.0.1:7999"


def parse(defaults: ZenohDefaults, argv: list[str], listen: bool = True) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_zenoh_arguments(parser, defaults, listen=listen)
    return parser.parse_args(argv)


def plan(defaults: ZenohDefaults, argv: list[str], listen: bool = True) -> list[tuple[Any, ...]]:
    """(mode, connect, listen) of each config the command would try, in order."""
    return [
        tuple(json.loads(c.get_json(k)) for k in ("mode", "connect/endpoints", "listen/endpoints"))
        for c in zc.configs_from_args(parse(defaults, argv, listen))
    ]


@pytest.mark.parametrize(
    ("defaults", "argv", "listen", "expected"),
    [
        (AGENT, [], True, [("peer", [DEFAULT], [ANY])]),
        (AGENT, ["--connect", OTHER], True, [("peer", [OTHER], [ANY])]),
        (AGENT, ["--connect", OTHER, "--mode", "client"], True, [("client", [OTHER], [])]),
        (AGENT, ["--listen", OTHER], True, [("peer", [], [OTHER])]),
        (OPERATOR, [], True, [("peer", [DEFAULT], [ANY])]),
        (OPERATOR, ["--connect", OTHER], True, [("peer", [OTHER], [ANY])]),
        (OPERATOR, ["--mode", "client"], True, [("client", [DEFAULT], [])]),
        (QUERY, [], True, [("client", [DEFAULT], [])]),
        (QUERY, ["--mode", "peer", "--connect", OTHER], True, [("peer", [OTHER], [ANY])]),
        (WATCHER, [], False, [("client", [DEFAULT], [])]),
        (WATCHER, ["--connect", OTHER], False, [("client", [OTHER], [])]),
        (WATCHER, ["--mode", "peer"], False, [("peer", [DEFAULT], [ANY])]),
        (SERVICE, [], True, [("peer", [DEFAULT], [ANY])]),
        (SERVICE, ["--mode", "client"], True, [("client", [DEFAULT], [])]),
        (SERVICE, ["--connect", OTHER], True, [("peer", [OTHER], [ANY])]),
        (SERVICE, ["--listen", OTHER], True, [("peer", [], [OTHER])]),
    ],
)
def test_defaults_apply_only_without_endpoint_options(
    defaults: ZenohDefaults, argv: list[str], listen: bool, expected: list[tuple[Any, ...]]
) -> None:
    assert plan(defaults, argv, listen) == expected


def test_a_config_file_replaces_the_defaults(tmp_path: Path) -> None:
    cfg = tmp_path / "z.json5"
    cfg.write_text(f'{{mode: "client", connect: {{endpoints: ["{OTHER}"]}}}}')
    assert plan(AGENT, ["--zenoh-config", str(cfg)]) == [("client", [OTHER], [])]
    assert plan(WATCHER, ["--zenoh-config", str(cfg)], listen=False) == [
        ("client", [OTHER], [])
    ]
    assert plan(SERVICE, ["--zenoh-config", str(cfg), "--mode", "peer"]) == [
        ("peer", [OTHER], [ANY])
    ]
    chosen = tmp_path / "listen.json5"
    chosen.write_text(f'{{mode: "peer", listen: {{endpoints: ["{OTHER}"]}}}}')
    assert plan(AGENT, ["--zenoh-config", str(chosen)]) == [("peer", [], [OTHER])]


def test_cfg_pairs_are_applied_last() -> None:
    args = parse(AGENT, ["--cfg", "transport/link/tx/lease:3000",
                         "--cfg", f'connect/endpoints:["{OTHER}"]'])
    (config,) = zc.configs_from_args(args)
    assert json.loads(config.get_json("transport/link/tx/lease")) == 3000
    assert json.loads(config.get_json("connect/endpoints")) == [OTHER]  # over the default
    assert json.loads(config.get_json("listen/endpoints")) == [ANY]


@pytest.mark.parametrize("pair", ["no-colon", ":3", "mode:", "mode:'server'", "nope/key:1"])
def test_bad_cfg_pairs_are_malformed_and_named(pair: str) -> None:
    with pytest.raises(KinesphereError) as info:
        zc.configs_from_args(parse(OPERATOR, ["--cfg", pair]))
    assert info.value.code == "malformed"
    assert info.value.message.startswith(f"--cfg {pair!r}")
    assert " at /" not in info.value.message


def test_session_takes_the_endpoint_or_joins_whoever_holds_it() -> None:
    """The databank rule, on a free port: the first session listens, the next one joins it."""
    endpoint = zc.loopback_endpoint()
    defaults = ZenohDefaults(connect=(), listen=(endpoint,),
                             fallback=ZenohDefaults(connect=(endpoint,), listen=(ANY,)))
    with zc.session_from_args(parse(defaults, [])) as first:
        with zc.session_from_args(parse(defaults, [])) as second:
            assert [str(z) for z in second.info.peers_zid()] == [str(first.zid())]
        with zc.session(zc.session_config(connect=[endpoint], scouting=False)) as third:
            assert [str(z) for z in third.info.peers_zid()] == [str(first.zid())]


def test_a_session_that_cannot_open_is_unavailable() -> None:
    with zc.loopback_hub() as (_hub, endpoint):
        with pytest.raises(KinesphereError) as info:
            zc.session_from_args(parse(OPERATOR, ["--listen", endpoint, "--connect", endpoint]))
    assert info.value.code == "unavailable"


def _subparsers(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser]]:
    out = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out.append((name, sub))
                out += [(f"{name} {n}", p) for n, p in _subparsers(sub)]
    return out


def test_every_command_with_zenoh_options_uses_the_shared_group() -> None:
    """A command that re-declares --connect by hand would re-code the rule: none may."""
    commands = _subparsers(build_parser())
    with_zenoh = [(n, p) for n, p in commands if "--connect" in p._option_string_actions]
    assert {n for n, _ in with_zenoh} >= {"agent", "databank serve", "query", "gamepad", "send",
                                          "play", "estop", "status", "ecl record"}
    for name, parser in with_zenoh:
        assert isinstance(parser.get_default("zenoh_defaults"), ZenohDefaults), name
        for option in ("--cfg", "--zenoh-config", "--mode", "--prefix"):
            assert option in parser._option_string_actions, f"{name} lacks {option}"
        group = next(g for g in parser._action_groups if g.title == "zenoh")
        assert group.description and parser.get_default("zenoh_defaults").describe() in (
            group.description
        ), name


def test_describe_names_every_default() -> None:
    hub = "'kinesphere router' listens there (the hub, which serves nothing else)."
    assert SERVICE.describe() == (
        f"connect to {DEFAULT} and listen on loopback, any port. {hub}"
    )
    assert QUERY.describe() == f"connect to {DEFAULT} (as a Zenoh client). {hub}"
    assert WATCHER.describe() == f"connect to {DEFAULT} (as a Zenoh client). {hub}"
    fallback = ZenohDefaults(connect=(), listen=(DEFAULT,), fallback=ZenohDefaults())
    assert fallback.describe() == f"listen on {DEFAULT}, or connect to {DEFAULT} if that fails."


def test_zenoh_sessions_close_as_context_managers() -> None:
    with zc.loopback_hub() as (_hub, endpoint):
        with zc.session_from_args(parse(OPERATOR, ["--connect", endpoint])) as s:
            assert isinstance(s, zenoh.Session)
        assert s.is_closed()


@pytest.mark.parametrize(("mode", "expected"),
                         [("peer", [ANY]), ("client", []), ("router", [DEFAULT])])
def test_nobody_listens_on_every_interface_unless_told(mode: str, expected: list[str]) -> None:
    """Zenoh's own default is every interface, in plain TCP; kinesphere's is loopback only."""
    config = zc.session_config(mode)
    assert "tcp/[::]" in config.get_json("listen/endpoints")  # what Zenoh would do
    assert json.loads(zc.listen_where_told(config).get_json("listen/endpoints")) == expected
    told = zc.session_config(mode, listen=[OTHER])
    assert json.loads(zc.listen_where_told(told).get_json("listen/endpoints")) == [OTHER]
