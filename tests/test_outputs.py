"""Safe outputs (pmsr_nn.outputs), the hardened YAML loader and the plausibility checks."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from pmsr_nn.config import MAX_YAML_DEPTH, MAX_YAML_NODES, load_yaml, parse_yaml_value
from pmsr_nn.errors import ConfigError, GeometryError, MeasurementError, OutputError
from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.outputs import (MARKER, atomic_file, atomic_folder, check_folder_target, check_target, clean_stale,
                             is_ours, output_kind, virtual_file_system, write_marker)
from pmsr_nn.plausibility import check_measurements


def tree(root):
    """{relative path: bytes} of every file under ``root``, and every folder (value None)."""
    out = {}
    for d, dirs, files in os.walk(root):
        for n in dirs:
            out[os.path.relpath(os.path.join(d, n), root)] = None
        for n in files:
            p = os.path.join(d, n)
            out[os.path.relpath(p, root)] = open(p, "rb").read()
    return out


@pytest.fixture
def cwd(tmp_path, monkeypatch):
    work = tmp_path / "work"
    (work / "user").mkdir(parents=True)
    (work / "user" / "notes.txt").write_text("mine")
    monkeypatch.chdir(work)
    return work


# -- outputs ---------------------------------------------------------------------------------

@pytest.mark.parametrize("target", [".", "..", "../..", "/", "~"])
def test_never_the_working_directory_a_parent_home_or_root(cwd, target):
    before = tree(cwd)
    with pytest.raises(OutputError, match="working directory or a parent|home folder or the file-system root"):
        with atomic_folder(os.path.expanduser(target) if target == "~" else target, command="evaluate", overwrite=True):
            pass
    assert tree(cwd) == before


def test_a_folder_we_did_not_write_is_never_replaced(cwd):
    before = tree(cwd)
    for overwrite in (False, True):
        with pytest.raises(OutputError, match="not written by pmsr"):
            with atomic_folder(cwd / "user", command="evaluate", overwrite=overwrite):
                pass
    assert tree(cwd) == before


def test_ours_is_replaced_only_with_overwrite_and_only_by_a_compatible_command(cwd):
    with atomic_folder(cwd / "res", command="evaluate") as tmp:
        (tmp / "a.txt").write_text("1")
    assert is_ours(cwd / "res") and output_kind(cwd / "res") == "evaluate"
    assert json.loads((cwd / "res" / MARKER).read_text())["command"] == "evaluate"
    with pytest.raises(OutputError, match="pass --overwrite"):
        check_folder_target(cwd / "res", overwrite=False)
    with pytest.raises(OutputError, match="holds the output of 'pmsr evaluate'"):
        check_folder_target(cwd / "res", overwrite=True, allow=("simulate",))
    with atomic_folder(cwd / "res", command="evaluate", overwrite=True) as tmp:
        (tmp / "b.txt").write_text("2")
    assert sorted(p.name for p in (cwd / "res").iterdir()) == [MARKER, "b.txt"]
    assert sorted(p.name for p in cwd.iterdir()) == ["res", "user"]  # nothing aside, nothing partial


@pytest.mark.parametrize("relation", ["same", "holds", "inside"])
def test_an_input_is_never_an_output(cwd, relation):
    (cwd / "shard").mkdir()
    (cwd / "shard" / "x").write_text("data")
    out = {"same": cwd / "shard", "holds": cwd, "inside": cwd / "shard" / "sub"}[relation]
    before = tree(cwd)
    with pytest.raises(OutputError):
        check_folder_target(out if relation != "holds" else cwd / ".." / cwd.name, overwrite=True,
                            inputs=[cwd / "shard"])
    with pytest.raises(OutputError, match="input"):
        check_folder_target(cwd / "shard" / "sub" if relation == "inside" else cwd / "shard", overwrite=True,
                            inputs=[cwd / "shard"])
    assert tree(cwd) == before


def test_a_symlink_is_never_followed_into_replacement(cwd):
    (cwd / "link").symlink_to(cwd / "user")
    with pytest.raises(OutputError, match="symbolic link"):
        check_folder_target(cwd / "link", overwrite=True)
    with pytest.raises(OutputError, match="symbolic link"):
        with atomic_file(cwd / "link", overwrite=True):
            pass
    assert (cwd / "user" / "notes.txt").read_text() == "mine"


def test_a_failure_inside_leaves_nothing_and_removes_created_parents(cwd):
    with pytest.raises(RuntimeError):
        with atomic_folder(cwd / "a" / "b" / "out", command="evaluate") as tmp:
            (tmp / "half.txt").write_text("x")
            raise RuntimeError("boom")
    assert sorted(p.name for p in cwd.iterdir()) == ["user"]


def test_a_marker_that_can_not_be_written_whole_leaves_the_earlier_one(cwd, monkeypatch):
    """A full disk while the marker is rewritten (e.g. a bank's, or a run's 'finished') keeps the
    earlier marker byte for byte and leaves no temporary."""
    import errno

    folder = cwd / "res"
    folder.mkdir()
    write_marker(folder, "evaluate", per_block=True)
    before = (folder / MARKER).read_bytes()
    real_fsync = os.fsync

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError, match="No space"):
        write_marker(folder, "evaluate", state="finished")
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert (folder / MARKER).read_bytes() == before and sorted(p.name for p in folder.iterdir()) == [MARKER]
    write_marker(folder, "evaluate", state="finished")
    assert json.loads((folder / MARKER).read_text())["state"] == "finished"


def test_a_marker_never_writes_or_removes_a_taken_temporary_name(cwd):
    folder = cwd / "res"
    folder.mkdir()
    write_marker(folder, "evaluate")
    before = (folder / MARKER).read_bytes()
    taken = folder / f".{MARKER}.partial-{os.getpid()}"
    taken.write_text("someone else's file\n")
    with pytest.raises(OutputError, match="is taken"):
        write_marker(folder, "evaluate", state="finished")
    assert taken.read_text() == "someone else's file\n" and (folder / MARKER).read_bytes() == before


def test_a_killed_writer_leaves_a_partial_that_the_next_write_removes(cwd):
    code = ("import os, sys; from pmsr_nn.outputs import atomic_folder\n"
            "with atomic_folder('res', command='evaluate') as t:\n"
            "    (t / 'half').write_text('x'); sys.stdout.write(str(os.getpid())); sys.stdout.flush(); os._exit(9)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=cwd)
    pid = int(p.stdout)
    assert (cwd / f".res.partial-{pid}").is_dir() and not (cwd / "res").exists()
    (cwd / ".res.partial-999999999").mkdir()  # not ours (no partial marker): kept
    with atomic_folder(cwd / "res", command="evaluate") as tmp:
        (tmp / "ok").write_text("1")
    assert not (cwd / f".res.partial-{pid}").exists() and (cwd / ".res.partial-999999999").is_dir()
    assert clean_stale(cwd / "res") == []


def test_a_taken_temporary_name_is_never_written_or_removed(cwd):
    pid = os.getpid()
    (cwd / f".res.partial-{pid}").mkdir()
    (cwd / f".res.partial-{pid}" / "x").write_text("someone's")
    (cwd / f".z.csv.partial-{pid}").write_text("someone's")
    before = tree(cwd)
    with pytest.raises(OutputError, match="cannot create the temporary folder"):
        with atomic_folder(cwd / "res", command="evaluate"):
            pass
    with pytest.raises(OutputError, match="temporary name .* is taken"):
        with atomic_file(cwd / "z.csv"):
            pass
    assert tree(cwd) == before


def test_what_appeared_at_the_target_during_the_work_is_kept(cwd):
    with pytest.raises(OutputError, match="not written by pmsr"):
        with atomic_folder(cwd / "res", command="evaluate") as tmp:
            (tmp / "a.txt").write_text("1")
            (cwd / "res").mkdir()  # the user makes the folder while the work runs
            (cwd / "res" / "mine.txt").write_text("mine")
    assert (cwd / "res" / "mine.txt").read_text() == "mine" and partial_names(cwd) == []


def partial_names(folder):
    return [p.name for p in folder.iterdir() if ".partial-" in p.name or ".old-" in p.name]


def test_atomic_file_refuses_existing_folders_and_unasked_overwrites(cwd):
    (cwd / "z.csv").write_text("old")
    with pytest.raises(OutputError, match="already exists"):
        with atomic_file(cwd / "z.csv"):
            pass
    with pytest.raises(OutputError, match="is a folder"):
        with atomic_file(cwd / "user", overwrite=True):
            pass
    with pytest.raises(OutputError, match="also an input"):
        with atomic_file(cwd / "z.csv", overwrite=True, inputs=[cwd / "z.csv"]):
            pass
    with pytest.raises(OutputError, match="must end in .csv"):
        with atomic_file(cwd / "z.txt", suffixes=(".csv",)):
            pass
    with pytest.raises(OutputError, match="a file, not a folder"):
        with atomic_file(cwd / "z.csv" / "inner.csv"):
            pass
    with atomic_file(cwd / "z.csv", overwrite=True) as tmp:
        tmp.write_text("new")
    assert (cwd / "z.csv").read_text() == "new" and sorted(p.name for p in cwd.iterdir()) == ["user", "z.csv"]


# -- YAML ------------------------------------------------------------------------------------

def billion_laughs(levels=9):
    lines = ["a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    return "\n".join(lines) + "\n"


def test_an_alias_bomb_is_refused_at_once():
    import time

    t0 = time.perf_counter()
    with pytest.raises(ConfigError, match="alias bomb"):
        parse_yaml_value(billion_laughs(), "bomb.yaml")
    assert time.perf_counter() - t0 < 1.0  # 9^9 = 387 M values if expanded; the check walks 82 nodes


def test_a_huge_plain_list_is_refused_as_it_is_read_and_not_called_an_alias_bomb():
    text = "noise: {range_m: 30.0}\nrange_m: [" + ",".join(["1"] * (5 * MAX_YAML_NODES)) + "]\n"
    with pytest.raises(ConfigError) as err:
        parse_yaml_value(text, "long.yaml")
    assert str(err.value) == (f"long.yaml: range_m (line 2) is a list of {5 * MAX_YAML_NODES:,} values; a config holds a "
                              f"few hundred values in all (at most {MAX_YAML_NODES:,}): is a long list pasted where a few "
                              "numbers belong?")
    parse_yaml_value("[" + ",".join(["1"] * (MAX_YAML_NODES - 1)) + "]", "fits.yaml")  # the list node + its values


@pytest.mark.parametrize("text, where", [
    ("a:\n  b:\n" + "  - 1\n" * MAX_YAML_NODES, f"a.b (line 3) holds more than {MAX_YAML_NODES:,} values"),  # block list
    ("a: [" + "[1, 2], " * MAX_YAML_NODES + "]", f"a (line 1) holds more than {MAX_YAML_NODES:,} values"),  # short lists
    ("z: 1\na: [{b: [" + "1, " * MAX_YAML_NODES + "]}]", f"a[0].b (line 2) is a list of {MAX_YAML_NODES:,} values"),
    ("a: ['" + "x', '" * MAX_YAML_NODES + "']", f"a (line 1) holds more than {MAX_YAML_NODES:,} values"),  # quoted
    ("".join(f"k{i}: {i}\n" for i in range(MAX_YAML_NODES)), "the document (line 1) holds more than"),
])
def test_the_refusal_of_a_long_document_names_its_longest_list(text, where):
    with pytest.raises(ConfigError) as err:
        parse_yaml_value(text, "c.yaml")
    assert str(err.value).startswith(f"c.yaml: {where}") and "alias" not in str(err.value)


def test_a_list_of_the_wrong_length_says_how_many_numbers_are_expected():
    from pmsr_nn.config import from_dict
    from pmsr_nn.simulation.recipe import NoiseSpec

    with pytest.raises(ConfigError) as err:
        from_dict(NoiseSpec, {"range_m": [16.0] * 19_000}, "recipe.noise")
    assert str(err.value) == "recipe.noise.range_m: expected 2 numbers, got 19,000"


def test_aliases_within_the_budget_still_work():
    text = "base: &b {lr: 1.0e-3, epochs: 5}\nrun: {<<: *b, epochs: 7}\ncopy: *b\n"
    assert parse_yaml_value(text) == {"base": {"lr": 1e-3, "epochs": 5}, "run": {"lr": 1e-3, "epochs": 7},
                                      "copy": {"lr": 1e-3, "epochs": 5}}
    just_over = "a: &a [" + ", ".join(["1"] * 1000) + "]\nb: [" + ", ".join(["*a"] * (MAX_YAML_NODES // 1000)) + "]\n"
    with pytest.raises(ConfigError, match="expand to more than"):
        parse_yaml_value(just_over)


@pytest.mark.parametrize("text, message", [
    ("a: &x [*x]\n", "refers to itself"),
    ("[" * 20_000 + "]" * 20_000, f"more than {MAX_YAML_DEPTH} levels"),
    ("seed: 1\nseed: 2\n", "duplicate key 'seed' \\(lines 1 and 2\\)"),
    ("a: {b: 1, b: 2}\n", "duplicate key 'b'"),
    ("a: 1\n---\nb: 2\n", "not valid YAML"),
    ("a: !!python/object/apply:os.system [ls]\n", "not valid YAML"),
])
def test_hostile_yaml_is_refused_in_one_line(text, message):
    with pytest.raises(ConfigError, match=message) as e:
        parse_yaml_value(text, "c.yaml")
    assert "\n" not in str(e.value) and len(str(e.value)) < 300


@pytest.mark.parametrize("text, value", [("3e-3", 3e-3), ("1e-7", 1e-7), ("1E+3", 1e3), ("1.0e5", 1e5), (".5", 0.5),
                                         ("-2e3", -2e3), ("5.", 5.0), ("1_000", 1000), ("0o17", 15), ("0x1f", 31),
                                         ("1e3", 1000.0)])
def test_numbers_in_every_notation_python_reads(text, value):
    got = parse_yaml_value(text)
    assert got == value and type(got) is type(value)


def test_config_files_utf8_bom_size(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_bytes(b"\xef\xbb\xbfseed: 3\n")
    assert load_yaml(p) == {"seed": 3}
    p.write_bytes("name: caf\u00e9\n".encode("latin-1"))
    with pytest.raises(ConfigError, match="not UTF-8 text \\(byte 0xe9 on line 1\\)"):
        load_yaml(p)
    p.write_bytes(b"a: " + b"x" * (5 * 2**20))
    with pytest.raises(ConfigError, match="may hold at most"):
        load_yaml(p)
    with pytest.raises(ConfigError, match="is a folder"):
        load_yaml(tmp_path)


# -- geometry and plausibility ---------------------------------------------------------------

def test_duplicate_sensors_are_refused_but_co_sited_channels_are_not():
    tx = Transmitter((0.0, 0.0), 1e8)
    with pytest.raises(GeometryError, match="receivers 0 and 1 are at the same position"):
        Geometry.all_pairs([tx], [Receiver((5e3, 0.0)), Receiver((5e3, 0.0))])
    with pytest.raises(GeometryError, match="same illuminator"):
        Geometry.all_pairs([tx, Transmitter((0.0, 0.0), 1e8)], [Receiver((5e3, 0.0))])
    with pytest.raises(GeometryError, match="listed twice"):
        Geometry((tx,), (Receiver((5e3, 0.0)),), ((0, 0), (0, 0)))
    g = Geometry.all_pairs([tx, Transmitter((0.0, 0.0), 9.5e7)], [Receiver((5e3, 0.0))])  # two FM channels, one mast
    assert g.n_pairs == 2


@pytest.fixture
def pair_geometry():
    return Geometry.all_pairs([Transmitter((0.0, 0.0), 1e8)], [Receiver((20e3, 0.0))])


COLS = ["range_1", "range_rate_1", "azimuth_1"]


def test_plausible_measurements_pass(pair_geometry):
    z = torch.tensor([[[30e3, -50.0, 0.3], [30.1e3, float("nan"), math.pi]]])
    check_measurements(z, COLS, pair_geometry, (torch.tensor([2e4, -300.0, -3.2]), torch.tensor([6e4, 300.0, 3.2])))


@pytest.mark.parametrize("row, message", [
    ([19e3 - 1001, 0.0, 0.1], "range_1 = 17999 is a bistatic range below the pair's baseline of 20000 m"),
    ([-5.0, 0.0, 0.1], "below the pair's baseline"),
    ([30e3, 0.0, 45.0], "azimuth_1 = 45 is an azimuth outside \\[-pi, pi\\]"),
    ([1e30, 0.0, 0.1], "far outside what the tracker was trained on"),
    ([30e3, 1e5, 0.1], "range_rate_1 = 100000 is far outside"),
])
def test_implausible_measurements_name_row_and_column(pair_geometry, row, message):
    z = torch.tensor([[[30e3, 0.0, 0.1], row]])
    span = (torch.tensor([2e4, -300.0, -3.2]), torch.tensor([6e4, 300.0, 3.2]))
    with pytest.raises(MeasurementError, match=message) as e:
        check_measurements(z, COLS, pair_geometry, span, where=lambda b, k: f"z.csv: row {k + 1}")
    assert str(e.value).startswith("z.csv: row 2:") and "--force" in str(e.value)


needs_proc = pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="no /proc on this system")


@needs_proc
@pytest.mark.parametrize("target", ["/proc/pmsr-x", "/proc/pmsr-x/y/z.csv"])
def test_nothing_is_written_to_a_virtual_file_system(cwd, target):
    with pytest.raises(OutputError) as err:
        check_target(target)
    assert str(err.value) == (f"--out {target}: /proc is a virtual file system with no disk behind it (like /proc or "
                              "/sys); give a folder on a disk")
    assert virtual_file_system(target) == virtual_file_system("/proc") == Path("/proc")
    assert virtual_file_system(cwd / "new" / "x") is None


@needs_proc
def test_an_os_error_on_a_virtual_file_system_says_so():
    from pmsr_nn.cli import describe_error

    assert describe_error(FileNotFoundError(2, "No such file or directory", "/proc/run/x")) == (
        2, "/proc/run/x: /proc is a virtual file system with no disk behind it (like /proc or /sys); give a folder on a disk")
    assert describe_error(FileNotFoundError(2, "No such file or directory", "nope/x")) == (
        2, "No such file or directory: nope/x")
