"""Hostile and broken files: checkpoints load without running code, and PATH.csv and
TARGETS.json are parsed strictly, never evaluated. Every bad file fails with one line
naming the file (and the line or target), as a ``ValueError`` the command line reports."""
from __future__ import annotations

import json
import os
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from motionopt.app.cli import main
from priors.checkpoint import CHECKPOINT_DIR, CheckpointError, load_prior, read_checkpoint
from problems.common import MAX_FILE_BYTES
from problems.edit import MAX_TARGETS, MAX_TARGETS_BYTES, load_targets
from problems.path_follow import MAX_NEW_SECONDS, MAX_PATH_POINTS, read_path_csv
from clips import DATA, BANDAI_30


SHIPPED = CHECKPOINT_DIR / "cmu-ccnet.pt"


class RunsCode:
    """Unpickling this runs a shell command that creates ``marker``."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


class WritesFile:
    """Unpickling this calls ``exec`` to write ``marker``."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (exec, (f"open({str(self.marker)!r}, 'w').write('ran')",))


class Harmless:
    """A plain class instance: not code, but not plain data either."""


@pytest.fixture(scope="module")
def real() -> dict:
    if not SHIPPED.exists():
        pytest.skip(f"needs the shipped checkpoint {SHIPPED}")
    return read_checkpoint(SHIPPED)


def refused(path: Path, match: str) -> str:
    """The one-line CheckpointError that reading ``path`` gives, checked against ``match``."""
    with pytest.raises(CheckpointError, match=match) as e:
        load_prior(path)
    text = str(e.value)
    assert "\n" not in text and str(path) in text and len(text) < 400, text
    return text


# ---- checkpoints ------------------------------------------------------------------------------------

@pytest.mark.parametrize("payload", [RunsCode, WritesFile])
@pytest.mark.parametrize("where", ["whole file", "inside a real checkpoint"])
def test_checkpoint_that_would_run_code_is_refused_and_runs_nothing(tmp_path, real, payload, where):
    marker = tmp_path / "MARKER"
    obj = payload(marker)
    path = tmp_path / "evil.pt"
    torch.save(obj if where == "whole file" else {**real, "metadata": {**real["metadata"], "x": obj}}, path)
    text = refused(path, "refused: it holds Python objects other than tensors and plain data")
    assert "could run code" in text and "only load checkpoints you trust" in text
    assert ("(posix.system)" if payload is RunsCode else "(exec)") in text
    with pytest.raises(CheckpointError, match="refused"):
        read_checkpoint(path)
    assert not marker.exists()


def test_checkpoint_with_a_class_instance_is_refused(tmp_path, real):
    path = tmp_path / "obj.pt"
    torch.save({**real, "config": Harmless()}, path)
    refused(path, r"refused: .*\(test_untrusted.Harmless\)")


def test_legacy_pickle_files_are_refused_without_running_code(tmp_path, real):
    marker = tmp_path / "MARKER"
    for protocol in (2, 4):  # 2 reaches the code's GLOBAL; 4 stops at an instruction the safe loader lacks
        path = tmp_path / f"legacy{protocol}.pt"
        with path.open("wb") as f:
            pickle.dump({"spec": RunsCode(marker)}, f, protocol=protocol)
        refused(path, "refused: it holds Python objects" if protocol == 2 else "not a motionopt checkpoint")
    path = tmp_path / "legacy-torch.pt"
    torch.save({"spec": RunsCode(marker)}, path, _use_new_zipfile_serialization=False)
    refused(path, "refused")
    assert not marker.exists()
    torch.save(real, path, _use_new_zipfile_serialization=False)  # the old format itself is fine
    assert load_prior(path).spec.joints == tuple(real["spec"]["joints"])


@pytest.mark.parametrize("fraction", [0.0, 0.001, 0.01, 0.5, 0.999])
def test_truncated_checkpoint_is_refused(tmp_path, fraction):
    if not SHIPPED.exists():
        pytest.skip(f"needs the shipped checkpoint {SHIPPED}")
    data = SHIPPED.read_bytes()
    path = tmp_path / "cut.pt"
    path.write_bytes(data[:int(len(data) * fraction)])
    refused(path, "is not a motionopt checkpoint")


@pytest.mark.parametrize("seed", range(3))
def test_random_bytes_are_refused(tmp_path, seed):
    path = tmp_path / "random.pt"
    path.write_bytes(np.random.default_rng(seed).bytes(4096))
    refused(path, "is not a motionopt checkpoint")


def test_folder_as_checkpoint_is_refused(tmp_path):
    refused(tmp_path, "is not a motionopt checkpoint")


def _edit(data: dict, change) -> dict:
    """A deep copy of checkpoint sections with ``change`` applied (a function of the copy)."""
    data = {k: (dict(v) if isinstance(v, dict) else v) for k, v in data.items()}
    change(data)
    return data


WRONG = [
    # (case, what to write: a function of the real checkpoint, words of the error)
    ("a list", lambda d: [1, 2, 3], "holds a list, not a dict of sections"),
    ("a tensor", lambda d: torch.zeros(3), "holds a Tensor"),
    ("a dict without the sections", lambda d: {"weights": torch.zeros(3)}, "lacks kind, config, spec"),
    ("no state_dict", lambda d: _edit(d, lambda c: c.pop("state_dict")), "lacks state_dict"),
    ("spec a string", lambda d: _edit(d, lambda c: c.update(spec="cmu")), "its spec must be a dict, got str"),
    ("metadata a list", lambda d: _edit(d, lambda c: c.update(metadata=[1])), "its metadata must be a dict, got list"),
    ("kind a number", lambda d: _edit(d, lambda c: c.update(kind=3)), "its kind must be a str, got int"),
    ("unknown kind", lambda d: _edit(d, lambda c: c.update(kind="Transformer")), "unknown prior kind 'Transformer'"),
    ("version a string", lambda d: _edit(d, lambda c: c["spec"].update(version="3")), "feature version '3'"),
    ("joints a string", lambda d: _edit(d, lambda c: c["spec"].update(joints="hip")), "joints must be a list"),
    ("fps a string", lambda d: _edit(d, lambda c: c["spec"].update(fps="30")), "fps must be a positive number"),
    ("fps not finite", lambda d: _edit(d, lambda c: c["spec"].update(fps=float("inf"))), "fps must be a positive"),
    ("unknown spec entry", lambda d: _edit(d, lambda c: c["spec"].update(extra=1)), "unknown entries"),
    ("contacts not modelled", lambda d: _edit(d, lambda c: c["spec"].update(contact_joints=["nose"])),
     "contact joints must be among its joints"),
    ("parents not indices", lambda d: _edit(d, lambda c: c["skeleton"].update(parents="0")), "parents must be"),
    ("offsets of two numbers",
     lambda d: _edit(d, lambda c: c["skeleton"].update(offsets=[o[:2] for o in c["skeleton"]["offsets"]])),
     r"offsets must be a list of \[x, y, z\]"),
    ("parents out of order",
     lambda d: _edit(d, lambda c: c["skeleton"].update(parents=[-1] + [5] * (len(c["skeleton"]["parents"]) - 1))),
     "its skeleton is invalid"),
    ("mean of the wrong size", lambda d: _edit(d, lambda c: c["normalizer"].update(mean=torch.zeros(5))),
     "normalizer mean must be 132 floats"),
    ("std a list", lambda d: _edit(d, lambda c: c["normalizer"].update(std=[1.0] * 132)), "got list"),
    ("std with a NaN", lambda d: _edit(d, lambda c: c["normalizer"].update(std=c["normalizer"]["std"] * np.nan)),
     "NaN or infinite"),
    ("a weight that is not a tensor", lambda d: _edit(d, lambda c: c["state_dict"].update(extra="w")),
     "state_dict must map parameter names to tensors"),
    ("a weight missing", lambda d: _edit(d, lambda c: c["state_dict"].pop("encoder.0.weight")),
     "encoder.0.weight is missing"),
    ("a config asking for a large network", lambda d: _edit(d, lambda c: c["config"].update(channels=8192)),
     r"its weights do not fit its config: blocks.0.conv.bias is \(\d+,\), the config makes \(16384,\)"),
    ("a config of another kind", lambda d: _edit(d, lambda c: c["config"].update(window=64)),
     "config does not describe a CCNetPrior"),
    ("a config value of the wrong type", lambda d: _edit(d, lambda c: c["config"].update(channels="64")),
     "config does not describe a CCNetPrior"),
    ("a config with a huge dilation", lambda d: _edit(d, lambda c: c["config"].update(dilations=(1, 10 ** 9))),
     "config must map names to numbers, strings or lists of them, whole numbers within 0 to 16384"),
    ("a config with nested lists", lambda d: _edit(d, lambda c: c["config"].update(dilations=[[1]])),
     "config must map names to numbers"),
    ("history not records", lambda d: _edit(d, lambda c: c["metadata"].update(history="long")),
     "history must be a list of records"),
]


@pytest.mark.parametrize("case,make,words", WRONG, ids=[c[0] for c in WRONG])
def test_checkpoint_of_the_wrong_structure_is_refused(tmp_path, real, case, make, words):
    path = tmp_path / "wrong.pt"
    torch.save(make(real), path)
    refused(path, words)


def test_untrusted_checkpoint_fails_the_command_in_one_line(capsys, tmp_path):
    marker = tmp_path / "MARKER"
    evil = tmp_path / "evil.pt"
    torch.save({"spec": RunsCode(marker)}, evil)
    out = tmp_path / "out.bvh"
    rc = main(["denoise", str(DATA / BANDAI_30), "--prior", str(evil), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and err[0].startswith("motionopt denoise: error: ") and "refused" in err[0]
    assert not marker.exists() and not out.exists()


# ---- PATH.csv ---------------------------------------------------------------------------------------

def write(path: Path, content: str | bytes) -> Path:
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return path


def bad_path(path: Path, content: str | bytes, match: str) -> None:
    write(path, content)
    with pytest.raises(ValueError, match=match) as e:
        read_path_csv(path)
    assert "\n" not in str(e.value) and len(str(e.value)) < 300, str(e.value)


def test_path_csv_accepts_a_bom_windows_line_ends_and_blank_lines(tmp_path):
    p = write(tmp_path / "p.csv", "\ufeffx,z,t\r\n\r\n0,0,0.5\r\n1.5,-2e-1,1\r\n")
    points, times = read_path_csv(p)
    np.testing.assert_array_equal(points, [[0, 0], [1.5, -0.2]])
    np.testing.assert_array_equal(times, [0.5, 1.0])


PATHS = [
    # (case, content, words of the error)
    ("empty", "", "empty"),
    ("blank lines only", "\n \n\t\n", "empty"),
    ("header only", "x,z\n", "at least 2 points, found 0"),
    ("not UTF-8", b"x,z\n0,0\n1,\xff\n", r":3: byte 0xff is not UTF-8; save the file as UTF-8 text"),
    ("a code cell", "x,z\n0,0\n__import__('os').system('true'),1\n", r":3: x value .* is not a number"),
    ("a NUL byte", "x,z\n0,0\n1,\x001\n", ":3: z value"),
    ("hex", "x,z\n0,0\n0x10,1\n", ":3: x value '0x10' is not a number"),
    ("NaN", "x,z\n0,0\n1,nan\n", ":3: z value 'nan' is not a finite number"),
    ("overflow", "x,z\n0,0\n1e999,1\n", ":3: x value '1e999' is not a finite number"),
    ("absurd coordinate", "x,z\n0,0\n2e4,1\n", ":3: x 20000 is farther than 10000 m"),
    ("too few cells", "x,z\n0,0\n1\n", ":3: expected 2 values"),
    ("too many cells", "x,z\n0,0\n1,2,3\n", ":3: expected 2 values"),
    ("a repeated t", "t,x,z\n0,0,0\n1,1,0\n1,2,0\n", ":4: t 1 does not come after the previous point's 1"),
    ("a decreasing t", "t,x,z\n0,0,0\n2,1,0\n1,2,0\n", ":4: t 1 does not come after"),
    ("a negative t", "t,x,z\n-1,0,0\n1,1,0\n", ":2: t -1 is negative"),
    ("a t beyond the cap", f"t,x,z\n0,0,0\n{MAX_NEW_SECONDS + 1:g},1,0\n", ":3: t 601 s is later than"),
    ("a huge cell", "x,z\n0,0\n1," + "9" * 200_000 + "\n", ":3: not CSV text"),
    ("a huge header", "x," + "z" * 10_000 + "\n0,0\n1,1\n", ":1: the header must name"),
]


@pytest.mark.parametrize("case,content,words", PATHS, ids=[c[0] for c in PATHS])
def test_path_csv_refuses_bad_content_naming_the_line(tmp_path, case, content, words):
    bad_path(tmp_path / "p.csv", content, words)


def test_path_csv_caps_points_and_file_size(tmp_path):
    rows = "".join(f"{i * 0.01:.2f},0\n" for i in range(MAX_PATH_POINTS + 1))
    bad_path(tmp_path / "long.csv", "x,z\n" + rows, f"more than {MAX_PATH_POINTS} points")
    assert len(read_path_csv(write(tmp_path / "ok.csv", "x,z\n" + rows.split("\n", 1)[1]))[0]) == MAX_PATH_POINTS
    big = tmp_path / "big.csv"
    with big.open("wb") as f:
        f.truncate(MAX_FILE_BYTES + 1)  # sparse: the size is checked before anything is read
    with pytest.raises(ValueError, match="big.csv is 50.0 MB; a CSV path of more than 50 MB is refused"):
        read_path_csv(big)


def test_path_csv_that_is_missing_or_a_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.csv does not exist"):
        read_path_csv(tmp_path / "nowhere.csv")
    with pytest.raises(ValueError, match="is not a file"):
        read_path_csv(tmp_path)


# ---- TARGETS.json -----------------------------------------------------------------------------------

GOOD = {"joint": "Hand_L", "frame": 3, "offset": [0, 0.1, 0]}


def bad_targets(path: Path, content: str | bytes, match: str) -> None:
    write(path, content)
    with pytest.raises(ValueError, match=match) as e:
        load_targets(path)
    assert "\n" not in str(e.value) and len(str(e.value)) < 300 and str(path) in str(e.value), str(e.value)


def test_targets_accept_a_bom_and_both_frame_forms(tmp_path):
    p = write(tmp_path / "t.json", "\ufeff" + json.dumps([GOOD, {"joint": "Head", "frame": [2, 5],
                                                                   "position": [1, 1.5, -2]}]))
    a, b = load_targets(p)
    assert a.frames == (3, 3) and a.offset == (0.0, 0.1, 0.0) and a.position is None
    assert b.frames == (2, 5) and b.position == (1.0, 1.5, -2.0)


def target(**change) -> str:
    """TARGETS.json text of one target: GOOD with ``change`` (a value None drops the key)."""
    item = {**GOOD, **change}
    return json.dumps([{k: v for k, v in item.items() if v is not None}])


TARGETS = [
    # (case, content, words of the error)
    ("empty", "", "the file is empty"),
    ("not UTF-8", b'[{"joint": "Hand_L",\n "frame": 3, "offset": [0, 0.1, \xfe]}]', r":2: byte 0xfe is not UTF-8"),
    ("not JSON", "[{'joint': 'Hand_L'}]", r":1: not valid JSON"),
    ("code", "__import__('os').system('true')", "not valid JSON"),
    ("an object at the top", json.dumps(GOOD), "expected a non-empty JSON list"),
    ("an empty list", "[]", "expected a non-empty JSON list"),
    ("a number in the list", "[1]", r"target 0: expected an object like"),
    ("frame a string", target(frame="3"), r"target 0: 'frame' must be a whole frame number .*got '3'"),
    ("frame a float", target(frame=3.5), "got 3.5"),
    ("frame a whole float", target(frame=3.0), "got 3.0"),
    ("frame a bool", target(frame=True), "got True"),
    ("frame a list of one", target(frame=[3]), r"got \[3\]"),
    ("frames backwards", target(frame=[5, 3]), "the last may not come before the first"),
    ("frame negative", target(frame=-1), "frames count from 0"),
    ("frame of 5000 digits", '[{"joint": "Hand_L", "frame": ' + "9" * 5000 + ', "offset": [0, 0, 0]}]',
     "the integer 999999999999... has 5000 digits"),
    ("position of two numbers", target(offset=None, position=[1, 2]), r"'position' must be three numbers"),
    ("offset of strings", target(offset=["0", "0", "0"]), r"'offset' must be three numbers"),
    ("offset with a bool", target(offset=[True, 0, 0]), r"'offset' must be three numbers"),
    ("offset NaN", '[{"joint": "Hand_L", "frame": 3, "offset": [NaN, 0, 0]}]', "not a number within 10000 m"),
    ("offset infinite", '[{"joint": "Hand_L", "frame": 3, "offset": [1e999, 0, 0]}]', "not a number within"),
    ("position absurd", target(offset=None, position=[0, 1e5, 0]), "not a number within 10000 m"),
    ("position and offset", target(position=[0, 1, 0]), "exactly one of 'position' or 'offset'"),
    ("neither", target(offset=None), "exactly one of 'position' or 'offset'"),
    ("an unknown key", target(jiont="Hand_R"), "unknown key 'jiont'"),
    ("no joint", target(joint=None), "needs 'joint' and 'frame'"),
    ("joint a number", target(joint=5), "'joint' must be a joint name, got 5"),
    ("joint a list", target(joint=["Hand_L"]), "'joint' must be a joint name"),
    ("a repeated key", '[{"joint": "Hand_L", "joint": "Head", "frame": 3, "offset": [0, 0, 0]}]',
     "gives 'joint' twice"),
    ("nested lists", "[" * 100_000 + "]" * 100_000, "nested too deeply"),
    ("nested objects", '{"a":' * 100_000 + "1" + "}" * 100_000, "nested too deeply"),
    ("too many targets", json.dumps([GOOD] * (MAX_TARGETS + 1)), f"{MAX_TARGETS + 1} targets; at most"),
]


@pytest.mark.parametrize("case,content,words", TARGETS, ids=[c[0] for c in TARGETS])
def test_targets_refuse_bad_content_naming_the_entry(tmp_path, case, content, words):
    bad_targets(tmp_path / "t.json", content, words)


def test_second_target_is_named_by_its_index(tmp_path):
    bad_targets(tmp_path / "t.json", json.dumps([GOOD, {**GOOD, "frame": "7"}]), "t.json: target 1: 'frame'")


def test_targets_file_too_large_is_refused_before_reading(tmp_path):
    big = tmp_path / "big.json"
    with big.open("wb") as f:
        f.truncate(MAX_TARGETS_BYTES + 1)
    with pytest.raises(ValueError, match="big.json is 5.0 MB; a JSON list of targets of more than 5 MB is refused"):
        load_targets(big)


@pytest.mark.parametrize("command,flag,name,content", [
    ("edit", "--targets", "t.json", "[" * 100_000),
    ("edit", "--targets", "t.json", b'[{"joint": "\xff"}]'),
    ("path-follow", "--path", "p.csv", b"x,z\n0,0\n\xfe,1\n"),
    ("path-follow", "--path", "p.csv", "x,z\n0,0\n1e9,1\n"),
])
def test_bad_user_files_fail_the_command_in_one_line(capsys, tmp_path, command, flag, name, content):
    f = write(tmp_path / name, content)
    rc = main([command, str(DATA / BANDAI_30), flag, str(f), "--out", str(tmp_path / "o.bvh")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and err[0].startswith(f"motionopt {command}: error: {f}"), err
    assert not (tmp_path / "o.bvh").exists()


def test_shipped_checkpoints_still_load(tmp_path):
    for path in sorted(CHECKPOINT_DIR.glob("*.pt")):
        if ".train-state" in path.name:
            continue
        copy = tmp_path / path.name
        shutil.copy(path, copy)
        assert load_prior(copy).spec.version == read_checkpoint(path)["spec"]["version"]
