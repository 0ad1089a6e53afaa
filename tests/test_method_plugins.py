"""Method kinds from another installed package: a tiny package "installed" into a temporary folder
(its module and a ``dist-info`` with the entry point of group ``pmsr_nn.methods``) is listed by
``pmsr methods``, runs through ``pmsr evaluate``, and its faults are one line each."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from pmsr_nn.cli import main
from pmsr_nn.methods import PLUGIN_GROUP, PLUGINS, REGISTRY, PluginError, forget_plugins, method_kind, registry

ROOT = Path(__file__).resolve().parents[1]
MODULE = "my_gnn_kind"
ENTRY = f"my_gnn = {MODULE}"
WHO = f"entry point '{ENTRY}' of distribution my-gnn-kind 0.1"

ORIGIN = '''
import torch
from pmsr_nn.methods import MethodKind, register
from pmsr_nn.trackers.base import Estimates


def run(call):
    """Every target's track at the origin, held while it lives."""
    z = call.product.z  # (B, N, K, m)
    B, N, K = z.shape[:3]
    x = torch.zeros(B, K, N, call.product.prior.x.shape[-1], dtype=torch.float64)
    return Estimates(x, call.alive.expand(B, K, N).clone())


register(MethodKind("my_gnn", "measurements", run, description="a test plugin: the origin, held"))
'''

FAULTS = {
    "fails to import": ("import not_a_module_of_anyone\n",
                        f"method-kind plugin {WHO} fails to load: ModuleNotFoundError: No module named "
                        "'not_a_module_of_anyone'"),
    "clashes with a built-in kind": (ORIGIN.replace('MethodKind("my_gnn"', 'MethodKind("ekf"'),
                                     f"method-kind plugin {WHO} registers method kind 'ekf', which is a built-in "
                                     "kind: rename it"),
    "registers nothing": ("X = 1\n", f"method-kind plugin {WHO} registers no method kind"),
}


def install(folder: Path, source: str, entry: str = ENTRY) -> None:
    """A package as pip would leave it in ``folder``: the module and its ``dist-info``."""
    (folder / f"{MODULE}.py").write_text(source)
    info = folder / f"{MODULE}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: my-gnn-kind\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{PLUGIN_GROUP}]\n{entry}\n")


@pytest.fixture
def site(tmp_path, monkeypatch):
    """A folder on ``sys.path`` to install into; the registry discovers plugins afresh before and after."""
    folder = tmp_path / "site"
    folder.mkdir()
    monkeypatch.syspath_prepend(str(folder))
    forget_plugins()
    sys.modules.pop(MODULE, None)
    yield folder
    forget_plugins()
    sys.modules.pop(MODULE, None)


def one_target(tmp_path: Path, kind: str) -> Path:
    d = {"name": "one", "seed": 3, "mc_runs": 2, "block_runs": 2, "warmup_steps": 5,
         "cases": [{"name": "c", "targets": [{"name": "a", "start_range_m": 4000.0, "start_bearing_deg": 130.0,
                                             "speed_mps": 10.0, "heading_deg": 20.0,
                                             "segments": [{"duration_s": 30.0}]}]}],
         "methods": [{"name": "mine", "kind": kind}, {"name": "EKF", "kind": "ekf"}]}
    path = tmp_path / "one.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


@pytest.mark.integration
def test_a_kind_of_another_package_is_listed_in_a_fresh_process(site):
    install(site, ORIGIN)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)])}
    out = subprocess.run([sys.executable, "-m", "pmsr_nn.cli", "methods"], env=env, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    block = next(b for b in out.stdout.split("\n\n") if b.startswith("my_gnn  "))
    assert block.splitlines()[1:] == ["    a test plugin: the origin, held", f"    from: module {MODULE}, {WHO}"]
    assert "ekf  (reads" in out.stdout  # the built-in kinds beside it


def test_a_kind_of_another_package_runs_through_evaluate(site, tmp_path, capsys):
    install(site, ORIGIN)
    assert method_kind("my_gnn").run.__module__ == MODULE and str(PLUGINS["my_gnn"]) == WHO
    assert main(["evaluate", str(one_target(tmp_path, "my_gnn")), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    case = json.loads((tmp_path / "out" / "results.json").read_text())["cases"]["c"]
    # its track sits at the origin: its error at each scan is the target's distance from the origin
    # (the same flight in every run), averaged over the target's scans
    distance = np.linalg.norm(np.array(case["truth_pos_m"]), axis=-1)
    assert case["methods"]["mine"]["rmse_pos_all_scans_m"] == pytest.approx(distance.mean(), rel=1e-12)
    assert case["methods"]["mine"]["kind"] == "my_gnn"


@pytest.mark.parametrize("fault", list(FAULTS))
def test_a_faulty_plugin_is_one_line_and_exit_2(site, capsys, fault):
    source, message = FAULTS[fault]
    install(site, source)
    assert main(["methods"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pmsr: error: {message}") and err.count("\n") == 1
    assert "my_gnn" not in REGISTRY and not PLUGINS and "ekf" in REGISTRY  # nothing half-registered
    with pytest.raises(PluginError, match="method-kind plugin"):  # and the next consultation says it again
        registry()


def test_a_fault_inside_a_plugin_kind_names_its_module_not_pmsr_nn(site, tmp_path, capsys):
    install(site, ORIGIN.replace('    z = call.product.z', '    raise RuntimeError("the gate is empty")\n    z = 0'))
    assert main(["evaluate", str(one_target(tmp_path, "my_gnn")), "--out", str(tmp_path / "out"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert err == (f"pmsr: error: unexpected RuntimeError: the gate is empty, raised in method kind 'my_gnn' of module "
                   f"{MODULE} ({WHO}): rerun with --debug for the traceback and report it to that code's authors\n")
    assert not (tmp_path / "out").exists()


def test_a_plugin_may_name_a_function_that_registers(site):
    install(site, ORIGIN.replace("\nregister(", "\ndef kinds():\n    register(") , entry=f"my_gnn = {MODULE}:kinds")
    assert registry()["my_gnn"].description == "a test plugin: the origin, held"
    assert str(PLUGINS["my_gnn"]) == f"entry point 'my_gnn = {MODULE}:kinds' of distribution my-gnn-kind 0.1"


def test_only_a_fault_on_a_plugins_code_is_laid_at_its_door(site):
    from pmsr_nn.cli import describe_error

    install(site, ORIGIN)
    kind = method_kind("my_gnn")
    with pytest.raises(AttributeError) as inside:
        kind.run(None)  # raised in the plugin's run
    with pytest.raises(KeyError) as outside:
        {}["x"]  # raised with no plugin's code on the traceback
    assert describe_error(inside.value)[1].endswith(f"raised in method kind 'my_gnn' of module {MODULE} ({WHO}): rerun "
                                                    "with --debug for the traceback and report it to that code's "
                                                    "authors")
    assert describe_error(outside.value) == (1, "unexpected KeyError: 'x'; this is a bug in pmsr_nn: rerun with --debug "
                                                "for the traceback and report it")


def test_a_fault_inside_a_users_own_kind_names_its_module_not_pmsr_nn(site, tmp_path, capsys):
    """A kind a user's own code registered (no entry point: their script calls ``register`` and then
    ``pmsr_nn.cli.main``) that raises is laid at that module's door, not called a bug of pmsr_nn."""
    from pmsr_nn.methods import MethodKind, register

    source = site / "my_script_kinds.py"
    source.write_text("def run(call):\n    raise ValueError('my gate is empty')\n")
    sys.modules.pop("my_script_kinds", None)
    import my_script_kinds

    register(MethodKind("my_own", "measurements", my_script_kinds.run, description="a user's kind"))
    try:
        assert main(["evaluate", str(one_target(tmp_path, "my_own")), "--out", str(tmp_path / "out"), "--quiet"]) == 1
    finally:
        del REGISTRY["my_own"]
        sys.modules.pop("my_script_kinds", None)
    err = capsys.readouterr().err
    assert err == ("pmsr: error: unexpected ValueError: my gate is empty, raised in method kind 'my_own' of module "
                   "my_script_kinds (registered by that module, not by pmsr_nn): rerun with --debug for the "
                   "traceback and report it to that code's authors\n")
    assert not (tmp_path / "out").exists()
