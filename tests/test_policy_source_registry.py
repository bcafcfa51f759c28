"""A new policy source is a new module and its line in ``registry.SCHEMES`` (DESIGN.md): what it takes is declared
in that module (``OPTIONS``, ``TAKES_FILE``) and a release reads it there. The release code named the sources that
take a file and those that take an action map itself: a new file-based source was frozen by its relative path, so
a release verified from another folder read that folder's file (or none), and ``--map`` was refused for it."""

from __future__ import annotations

import sys

import pytest
from release_helpers import CELL, replay_file

import cellguard.policy
from cellguard.errors import ConfigError
from cellguard.policy import registry
from cellguard.release.bundle import create_bundle, verify_bundle
from cellguard.release.errors import ReleaseError

# A file-based source that takes an action map, written as a new source is: its own module, declaring what it takes
NEW_SOURCE = '''
from cellguard.policy.adapter import split_options
from cellguard.policy.replay import make_replay_policy

OPTIONS = {"map": "action map YAML file"}
TAKES_FILE = True


def make_policy(arg, cell):
    target, _ = split_options(arg, OPTIONS, "npzprog")
    return make_replay_policy(target, cell)
'''


@pytest.fixture
def npzprog(tmp_path, monkeypatch):
    """The source ``npzprog:FILE`` registered the documented way, and folders a/ and b/ each holding a prog.npz
    of other bytes; the test runs in a/."""
    (tmp_path / "npzprog_source.py").write_text(NEW_SOURCE)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(registry.SCHEMES, "npzprog", "npzprog_source:make_policy")
    for folder, offset in (("a", 0.0), ("b", 0.01)):
        (tmp_path / folder).mkdir()
        replay_file(tmp_path / folder / "prog.npz", offset)
    monkeypatch.chdir(tmp_path / "a")
    return tmp_path


def test_a_new_sources_file_is_frozen_by_its_absolute_path_and_verifies_from_elsewhere(npzprog, monkeypatch):
    bundle = create_bundle("npzprog:prog.npz", None, CELL, None)
    assert bundle.manifest["policy"]["spec"] == f"npzprog:{npzprog / 'a' / 'prog.npz'}"
    monkeypatch.chdir(npzprog / "b")
    verify_bundle(bundle)  # a/prog.npz, as frozen: b/prog.npz holds other bytes


def test_a_new_source_that_declares_a_map_takes_map_and_refuses_it_as_an_option(npzprog):
    amap = npzprog / "map.yaml"
    amap.write_text("robot: arm-pick-place\nactions:\n  - {name: a, joint: elbow, unit: rad}\n")
    bundle = create_bundle("npzprog:prog.npz", amap, CELL, None)
    assert bundle.manifest["action_map"]["path"] == str(amap.resolve())
    with pytest.raises(ReleaseError, match=r"^--policy: give the action map with --map, not \?map=$"):
        create_bundle(f"npzprog:prog.npz?ma%70={amap}", None, CELL, None)
    with pytest.raises(ReleaseError, match=r"--map: the scripted policy .* \(the .*npzprog policies do\)$"):
        create_bundle("scripted", amap, CELL, None)


@pytest.mark.parametrize("scheme", list(registry.SCHEMES))
def test_every_source_declares_what_it_takes(scheme):
    source = registry.source(scheme)
    assert isinstance(source.OPTIONS, dict) and isinstance(source.TAKES_FILE, bool)


def test_a_release_imports_only_its_own_source(monkeypatch):
    """Every create imported all the adapters: without openpi's msgpack (an extra) no release could be created."""
    monkeypatch.setitem(sys.modules, "msgpack", None)
    for module in ("cellguard.policy.openpi", "cellguard.policy.wire"):
        monkeypatch.delitem(sys.modules, module, raising=False)
        monkeypatch.delattr(cellguard.policy, module.rpartition(".")[2], raising=False)
    bundle = create_bundle("scripted", None, CELL, None)
    assert bundle.manifest["policy"]["spec"] == "scripted"


def test_a_source_whose_extra_is_not_installed_is_one_line_naming_the_extra(monkeypatch, tmp_path):
    """Without openpi's msgpack, `policy: openpi:...` was a ModuleNotFoundError traceback; --map with scripted listed
    the sources that take a map by importing them all."""
    monkeypatch.setitem(sys.modules, "msgpack", None)
    for module in ("cellguard.policy.openpi", "cellguard.policy.wire"):
        monkeypatch.delitem(sys.modules, module, raising=False)
        monkeypatch.delattr(cellguard.policy, module.rpartition(".")[2], raising=False)
    with pytest.raises(ConfigError, match=r"^policy source openpi: needs the Python package 'msgpack', which is not "
                                          r"installed \(pip install 'cellguard\[openpi\]'\)$"):
        registry.source("openpi")
    with pytest.raises(ReleaseError, match=r"--map: the scripted policy .* \(the onnx, lerobot policies do\)$"):
        create_bundle("scripted", tmp_path / "map.yaml", CELL, None)
