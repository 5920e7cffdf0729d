"""Files are untrusted input (issue 14, items 5-6; docs/cli.md "Errors in files").

Every hostile kind of config, profile, task and calibration file gives one line per
problem, ``FILE: field: reason`` (``FILE:LINE:COLUMN: ...`` where the problem has a place),
and exit code 2 through the real CLI, never a traceback and never a hang, before anything
is started. Recordings are in tests/unit/test_recording.py, the semantic checks at load in
tests/unit/test_config.py. A property-based fuzz of config files closes the file.

(Its tests with real peers: tests/system/test_hostile_files.py.)
"""

from __future__ import annotations

import importlib
import json
import os
import signal
import stat
import tempfile
from pathlib import Path

import pytest
import yaml
from fluidsense import cli
from fluidsense.common.errors import ConfigError
from fluidsense.common.files import YAML_MAX_BYTES
from fluidsense.common.models import StrictModel
from fluidsense.controller.config import load_cell_config, load_profile, validate
from fluidsense.controller.config.yamlfile import MAX_DEPTH, MAX_NODES
from fluidsense.controller.sensing.calibration import MAX_FILE_BYTES, Calibration
from fluidsense.tasks.config import SortingTask, load_task
from hypothesis import HealthCheck, given, settings
from support.configs import read, task_config
from support.cli import Ran, run_cli
from support.harness import REPO, sim_config

from lab.bench import fuzz_files


def cell_data(tmp_path: Path) -> dict:
    return yaml.safe_load(sim_config(tmp_path).read_text())


def write(tmp_path: Path, name: str, text: str | bytes) -> Path:
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def refused(load, path: Path) -> str:
    """The message of the ConfigError ``load(path)`` raises (one line)."""
    with pytest.raises(ConfigError) as err:
        load(path)
    msg = str(err.value)
    assert "\n" not in msg and "Traceback" not in msg, msg
    return msg


@pytest.fixture
def fluidsense(capsys):
    """The CLI in this process (``fluidsense.cli.main``), from ``cwd``: what it prints and
    returns; a hang fails the test through the tier's timeout, and anything it would start
    (a socket, a process) fails it through the tier's guard."""
    def run(*args: str, cwd: Path = REPO) -> Ran:
        return run_cli(capsys, *args, cwd=cwd)
    return run


def one_error(out: Ran, expected: str) -> None:
    """Exit code 2 and exactly one line on stderr, the expected one, nothing on stdout."""
    assert out.returncode == 2, (out.returncode, out.stderr)
    assert out.stderr.splitlines() == [f"fluidsense: error: {expected}"], out.stderr
    assert out.stdout == ""


# ----------------------------------------------------------------- what a file is
def test_a_fifo_is_refused_without_blocking(tmp_path, fluidsense):
    """Opening a FIFO for reading blocks until a writer comes: it is refused by type
    first, so `run` exits at once (the tier's timeout turns a hang into a failure)."""
    fifo = tmp_path / "cell.yaml"
    os.mkfifo(fifo)
    out = fluidsense("run", "--config", str(fifo), cwd=tmp_path)
    one_error(out, f"{fifo}: cannot read: not a regular file (a FIFO)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell.yaml"]  # no recording dir, no socket


@pytest.mark.parametrize("kind", ["dev-zero", "directory", "socket", "missing", "fifo"])
def test_a_profile_path_that_is_not_a_regular_file_names_the_cell_file(tmp_path, kind):
    target = {"dev-zero": Path("/dev/zero"), "directory": tmp_path, "missing": tmp_path / "nope.yaml"}.get(
        kind, tmp_path / kind)
    if kind == "fifo":
        os.mkfifo(target)
    if kind == "socket":  # a socket's file, as a bound unix socket leaves it (nothing listens)
        os.mknod(target, stat.S_IFSOCK | 0o600)
    path = sim_config(tmp_path, profile=str(target), check=False)
    msg = refused(load_cell_config, path)
    what = {"dev-zero": "a character device", "directory": "a directory", "socket": "a socket", "fifo": "a FIFO"}
    if kind == "missing":
        assert msg == f"{path}: profile: {target}: No such file or directory"
    else:
        assert msg == f"{path}: profile: {target} is not a regular file ({what[kind]})"


def test_a_file_larger_than_its_cap_is_not_read(tmp_path):
    big = tmp_path / "big.yaml"
    with open(big, "wb") as f:  # sparse: the size is what counts, nothing is read
        f.truncate(YAML_MAX_BYTES + 1)
    assert refused(load_cell_config, big) == f"{big}: cannot read: larger than the 1 MB a YAML file may have"
    cal = tmp_path / "big.json"
    with open(cal, "wb") as f:
        f.truncate(MAX_FILE_BYTES + 1)
    assert refused(Calibration.load, cal) == f"{cal}: cannot read: larger than the 16 MB a calibration file may have"


def test_a_nul_byte_in_a_file_name_is_an_error_not_a_valueerror(tmp_path):
    assert refused(load_cell_config, Path(f"{tmp_path}/a\0b.yaml")) == \
        f"{tmp_path}/a\\0b.yaml: cannot read: the file name contains a NUL byte"
    assert "NUL" in refused(Calibration.load, f"{tmp_path}/a\0b.json")


# ----------------------------------------------------------------- what a YAML file holds
def test_bytes_that_are_not_utf8_give_line_and_column(tmp_path):
    path = write(tmp_path, "cell.yaml", b"driver:\n  kind: s\xffm\n")
    assert refused(load_cell_config, path) == f"{path}:2:10: cannot read: not UTF-8 text (byte 0xff)"


def test_an_empty_and_a_truncated_file(tmp_path):
    empty = write(tmp_path, "empty.yaml", "")
    assert refused(load_cell_config, empty) == f"{empty}: (top level): the file is empty"
    text = yaml.safe_dump(cell_data(tmp_path), default_flow_style=True)
    cut = write(tmp_path, "cut.yaml", text[: len(text) // 2])  # inside a flow mapping
    msg = refused(load_cell_config, cut)
    assert msg.startswith(f"{cut}:") and msg.endswith(": YAML syntax: found unexpected end of stream")


@pytest.mark.parametrize("opening", ["[", "{a: ", "- "])
def test_nesting_deeper_than_the_limit_is_refused_not_a_recursion_error(tmp_path, opening):
    closing = {"[": "]", "{a: ": "}", "- ": ""}[opening]
    path = write(tmp_path, "deep.yaml", "driver:\n  " + opening * 3000 + "1" + closing * 3000 + "\n")
    msg = refused(load_cell_config, path)
    step = "a" if opening == "{a: " else "0"
    # the path shown stops after eight levels
    assert msg.startswith(f"{path}:2:") and msg.endswith(f": driver{f'.{step}' * 7}...: nested more than "
                                                         f"{MAX_DEPTH} levels deep")


def test_an_alias_bomb_is_refused_while_it_is_built(tmp_path):
    """Nine levels of ten aliases each would be 10^9 values once expanded."""
    lines = ["a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    lines += [f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 10) + "]" for k in range(1, 9)]
    path = write(tmp_path, "bomb.yaml", "\n".join(lines) + "\ndriver: *a8\n")
    msg = refused(load_cell_config, path)
    # refused at the fifth level, the first to pass MAX_NODES, long before the ninth
    assert msg == f"{path}:5:45: a4.7: more than {MAX_NODES} values once aliases are expanded"


def test_an_alias_inside_its_own_anchor_is_refused(tmp_path):
    path = write(tmp_path, "cycle.yaml", "driver: &d {kind: sim, scene: *d}\n")
    assert refused(load_cell_config, path) == f"{path}:1:31: driver.scene: alias *d inside the node it names (a cycle)"


def test_ordinary_aliases_and_merge_keys_still_load(tmp_path):
    data = cell_data(tmp_path)
    data["publisher"]["cmd"] = "*cmd"  # placeholder for the alias below
    text = yaml.safe_dump(data).replace("'*cmd'", "*cmd")
    text = text.replace("publisher:", "endpoint: &cmd " + json.dumps(cell_data(tmp_path)["publisher"]["cmd"])
                        + "\npublisher:", 1)
    path = write(tmp_path, "anchors.yaml", text)
    with pytest.raises(ConfigError, match=r"endpoint: unknown field"):  # aliases resolve; the extra key is refused
        load_cell_config(path)
    profile = write(tmp_path, "merge.yaml", "name: p\nsequence:\n  windows:\n"
                    "    - &w {name: eq, start_s: 4, end_s: 5}\n"
                    "    - {<<: *w, name: late, start_s: 5, end_s: 6}\n")
    assert [w.name for w in load_profile(profile).sequence.windows] == ["eq", "late"]


def test_a_duplicate_key_names_the_key_and_both_lines(tmp_path):
    data = cell_data(tmp_path)
    text = yaml.safe_dump(data)
    path = write(tmp_path, "dup.yaml", text + "driver: {kind: sim}\n")
    first = text.splitlines().index(next(line for line in text.splitlines() if line.startswith("driver:"))) + 1
    last = len(text.splitlines()) + 1
    assert refused(load_cell_config, path) == \
        f"{path}:{last}:1: driver: key 'driver' given twice (first at line {first})"
    nested = write(tmp_path, "nested.yaml", "name: p\nsequence:\n  p0_kpa: 40\n  charge_s: 5\n  p0_kpa: 60\n")
    assert refused(load_profile, nested) == f"{nested}:5:3: sequence.p0_kpa: key 'p0_kpa' given twice (first at line 3)"


@pytest.mark.parametrize("value", [".nan", ".inf", "-.Inf", "1e999"])
def test_a_number_that_is_not_finite_is_refused_where_it_is(tmp_path, value):
    path = write(tmp_path, "p.yaml", f"name: p\nsequence:\n  p0_kpa: {value}\n")
    assert refused(load_profile, path) == f"{path}:3:11: sequence.p0_kpa: {value!r} is not a finite number"


def test_nan_in_a_task_field_is_refused(tmp_path):
    task = read(task_config(tmp_path, "sorting"))
    path = write(tmp_path, "task.yaml", yaml.safe_dump(task).replace("order_mm:\n- 60", "order_mm:\n- .nan"))
    msg = refused(load_task, path)
    assert msg.startswith(f"{path}:") and msg.endswith(": order_mm.0: '.nan' is not a finite number")
    task["order_mm"] = [float("nan"), 40.0]  # the same through the model (a task built in code)
    with pytest.raises(ConfigError, match=rf"^{path}: order_mm.0: Input should be a finite number$"):
        validate(SortingTask, task, path)


def test_a_nul_character_in_a_string_is_refused(tmp_path):
    path = write(tmp_path, "cell.yaml", 'driver: {kind: sim}\nprofile: "pro\\0file.yaml"\n')
    assert refused(load_cell_config, path) == f"{path}:2:10: profile: a NUL character in a string"


def test_an_explicit_tag_that_cannot_be_built_and_a_python_tag(tmp_path):
    path = write(tmp_path, "tag.yaml", "name: !!int abc\n")
    assert refused(load_profile, path).startswith(f"{path}: YAML value: invalid literal for int()")
    evil = write(tmp_path, "evil.yaml", "name: !!python/object/apply:os.system ['touch pwned']\n")
    assert "YAML syntax: could not determine a constructor" in refused(load_profile, evil)
    assert not (tmp_path / "pwned").exists() and not Path("pwned").exists()


def test_an_integer_with_thousands_of_digits_is_refused_before_python_converts_it(tmp_path):
    path = write(tmp_path, "p.yaml", "name: p\nsequence: {smoothing_samples: " + "9" * 5000 + "}\n")
    assert refused(load_profile, path) == f"{path}:2:31: sequence.smoothing_samples: an integer of more than 40 digits"


# ----------------------------------------------------------------- numbers are numbers
@pytest.mark.parametrize("text, reason", [
    ('"63"', "Input should be a valid number"),
    ("true", "Input should be a valid number"),
    ("yes", "Input should be a valid number"),
    ("[63]", "Input should be a valid number"),
])
def test_a_string_or_boolean_is_not_a_number(tmp_path, text, reason):
    path = write(tmp_path, "p.yaml", f"name: p\nsequence:\n  p0_kpa: {text}\n")
    assert refused(load_profile, path) == f"{path}: sequence.p0_kpa: {reason}"


def test_an_integer_field_takes_no_float_and_a_float_field_takes_an_integer(tmp_path):
    path = write(tmp_path, "p.yaml", "name: p\nsequence: {smoothing_samples: 21.0}\n")
    assert refused(load_profile, path) == f"{path}: sequence.smoothing_samples: Input should be a valid integer"
    ok = write(tmp_path, "ok.yaml", "name: p\nsequence: {p0_kpa: 63, charge_s: 1e1}\n")
    seq = load_profile(ok).sequence
    assert seq.p0_kpa == 63.0 and seq.charge_s == 10.0  # 1e1: a number (YAML 1.2), not the string PyYAML made


def test_a_date_shaped_name_stays_a_string(tmp_path):
    path = write(tmp_path, "p.yaml", "name: 2024-13-45\n")  # PyYAML's timestamp resolver raised ValueError
    assert load_profile(path).name == "2024-13-45"


FILE_MODULES = ["fluidsense.common.hardware", "fluidsense.common.scenes", "fluidsense.common.world", "fluidsense.drivers.registry", "fluidsense.drivers.sampler.config",
                "fluidsense.drivers.reconnect", "fluidsense.drivers.recording.config",
                "fluidsense.drivers.ur.box", "fluidsense.common.wiring", "fluidsense.drivers.ur.config", "fluidsense.drivers.modbus.config", "fluidsense.controller.config",
                "fluidsense.controller.sensing.calibration", "fluidsense.tasks.config"]


def _numbers(schema) -> list[dict]:
    """The number schemas of a model, but those of free-form JSON values (a poller's
    kwargs, a calibration's scene metadata), which are not fields."""
    out, todo = [], [schema]
    while todo:
        node = todo.pop()
        if isinstance(node, dict):
            if "pydantic_internal_union_tag_key" in (node.get("metadata") or {}):
                continue
            if node.get("type") in ("float", "int"):
                out.append(node)
            todo.extend(node.values())
        elif isinstance(node, list):
            todo.extend(node)
    return out


def test_every_number_of_every_file_model_is_strict_and_finite():
    """A new field declared ``float`` instead of ``Real`` would coerce "63" again."""
    for name in FILE_MODULES:
        importlib.import_module(name)
    models, todo = [], list(StrictModel.__subclasses__())
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        if cls.__module__ in FILE_MODULES:
            models.append(cls)
    assert len(models) > 40
    for model in models:
        for schema in _numbers(model.__pydantic_core_schema__):
            assert schema.get("strict") is True, (model.__name__, schema)
            if schema["type"] == "float":
                assert schema.get("allow_inf_nan") is False, (model.__name__, schema)


# ----------------------------------------------------------------- calibrations
def good_calibration() -> dict:
    return {"format": "fluidsense-calibration/1", "profile": "linear-actuator", "method": "tank", "feature": "p_eq",
            "feature_unit": "kPa", "scene": {"kind": "wall"}, "target": "distance_mm", "target_unit": "mm",
            "fit": "linear", "coeffs": [-0.04, 22.6], "x": [0, 10, 20, 30], "y": [22.6, 22.2, 21.8, 21.4]}


CALIBRATIONS = {
    "nan": (lambda g: json.dumps(g).replace("22.2", "NaN"), "not a calibration file: NaN is not a number a "
            "calibration can hold"),
    "null": (lambda g: json.dumps({**g, "coeffs": [None, 1]}), "coeffs.0: Input should be a valid number"),
    "string": (lambda g: json.dumps({**g, "y": ["22.6", 1, 2, 3]}), "y.0: Input should be a valid number"),
    "deep": (lambda g: json.dumps({**g, "scene": {"a": json.loads("[" * 50 + "]" * 50)}}),
             "not a calibration file: JSON nested more than 16 levels deep"),
    "very deep": (lambda g: json.dumps(g)[:-1] + ', "window": ' + "[" * 100_000 + "]" * 100_000 + "}",
                  "not a calibration file: JSON nested too deeply"),
    "lengths": (lambda g: json.dumps({**g, "y": [1.0, 2.0]}), "y: 2 features for 4 targets"),
    "coefficients": (lambda g: json.dumps({**g, "coeffs": [1.0, 2.0, 3.0]}),
                     "coeffs: a linear fit has 2 coefficients, got 3"),
    "nul in the profile name": (lambda g: json.dumps({**g, "profile": "linear\u0000actuator"}),
                                "profile: String should match pattern '^[^\\x00-\\x1f]+$'"),
    "other format": (lambda g: json.dumps({**g, "format": "x"}),
                     "format: not a calibration file (format is not 'fluidsense-calibration/1')"),
}


@pytest.mark.parametrize("kind", CALIBRATIONS)
def test_a_hostile_calibration_names_file_and_field(tmp_path, kind):
    make, reason = CALIBRATIONS[kind]
    path = write(tmp_path, "cal.json", make(good_calibration()))
    assert refused(Calibration.load, path) == f"{path}: {reason}"


def test_a_truncated_calibration_and_a_valid_one(tmp_path):
    text = json.dumps(good_calibration())
    path = write(tmp_path, "cut.json", text[:60])
    assert refused(Calibration.load, path) == f"{path}:1:61: not a calibration file: JSON: Unterminated string " \
        "starting at" or refused(Calibration.load, path).startswith(f"{path}:1:")
    ok = write(tmp_path, "ok.json", text)
    assert Calibration.load(ok).invert(21.8).estimate == pytest.approx(20.0)


def test_sense_with_a_hostile_calibration_exits_2_before_anything_runs(tmp_path, fluidsense):
    cal = write(tmp_path, "cal.json", json.dumps({**good_calibration(), "residual_sd": "0.1"}))
    out = fluidsense("sense", "-k", str(cal), "--profile", "linear-actuator", cwd=tmp_path)
    one_error(out, f"{cal}: residual_sd: Input should be a valid number")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.json"]
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    one_error(fluidsense("sense", "-k", str(fifo), cwd=tmp_path),
              f"{fifo}: cannot read: not a regular file (a FIFO)")


# ----------------------------------------------------------------- through the CLI
def test_run_with_a_duplicate_key_exits_2_and_starts_nothing(tmp_path, fluidsense):
    path = sim_config(tmp_path)
    data = yaml.safe_load(path.read_text())
    text = path.read_text() + "log_level: INFO\nlog_level: DEBUG\n"
    path.write_text(text)
    line = len(text.splitlines())
    out = fluidsense("run", "--config", str(path), cwd=tmp_path)
    one_error(out, f"{path}:{line}:1: log_level: key 'log_level' given twice (first at line {line - 1})")
    assert not (tmp_path / "runs").exists()  # no recording was opened
    for endpoint in data["publisher"].values():
        assert not Path(endpoint.removeprefix("ipc://")).exists()  # no socket was bound


def test_task_run_with_a_hostile_task_file_exits_2(tmp_path, fluidsense):
    path = task_config(tmp_path, "sorting", check=False, motion={"speed_m_s": "fast"})
    one_error(fluidsense("task", "run", str(path), cwd=tmp_path),
              f"{path}: motion.speed_m_s: Input should be a valid number")
    other = task_config(tmp_path, "sorting", check=False, cell="no-such-cell.yaml")
    one_error(fluidsense("task", "run", str(other), cwd=tmp_path),
              f"{other}: cell: {tmp_path}/no-such-cell.yaml: No such file or directory")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([path.name, other.name])


def test_a_config_with_several_problems_gives_one_prefixed_line_each(tmp_path, fluidsense):
    path = sim_config(tmp_path, check=False, driver={"rate_hz": "fast", "seed": -1})
    out = fluidsense("run", "--config", str(path), cwd=tmp_path)
    assert out.returncode == 2
    assert out.stderr.splitlines() == [f"fluidsense: error: {path}: driver.rate_hz: Input should be a valid number",
                                       f"fluidsense: error: {path}: driver.seed: Input should be greater than or "
                                       "equal to 0"]


def test_help_shows_the_exit_codes(fluidsense):
    out = fluidsense("--help")
    assert out.returncode == 0
    lines = out.stdout[out.stdout.index("exit codes:"):].splitlines()[1:]
    assert [int(line.split()[0]) for line in lines] == [0, 1, 2, 3, 4, 129, 130, 143]
    assert "bad input" in lines[2] and "timeout" in lines[3] and "SIGHUP" in lines[5] and "Ctrl-C" in lines[6]
    assert "SIGTERM" in lines[7]


@pytest.mark.parametrize("raised, code", [
    (ConfigError("f.yaml: x: bad"), cli.EXIT_BAD_INPUT),
    (TimeoutError("no reply"), cli.EXIT_TIMEOUT),
    (KeyboardInterrupt(), cli.EXIT_INTERRUPTED),
])
def test_the_cli_maps_errors_to_exit_codes(monkeypatch, capsys, raised, code):
    """The command is replaced by one that raises (a mock of a command, not of the
    mapping under test): the exit code comes from fluidsense.cli alone."""
    import fluidsense.cli.subcommands.replay as replay_command

    def fail(args):
        raise raised

    monkeypatch.setattr(replay_command, "main", fail)
    assert cli.main(["replay", "x.mcap"]) == code
    err = capsys.readouterr().err
    assert err == ("" if code == cli.EXIT_INTERRUPTED else f"fluidsense: error: {raised}\n")


# ----------------------------------------------------------------- fuzz
class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang("a load did not end within 10 s")


@settings(max_examples=300, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=fuzz_files.hostile_cases())
def test_fuzzed_config_files_load_or_give_one_line_per_problem(case):
    """Random bytes, deep nesting, aliases, duplicate keys, special files and shipped
    configs with one field made hostile: each loads or is a ConfigError whose every line
    names a file of the case. A load that does not end raises Hang (SIGALRM)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = fuzz_files.write(case, Path(tmp))
        old = signal.signal(signal.SIGALRM, _alarm)
        signal.setitimer(signal.ITIMER_REAL, 10.0)
        try:
            result, detail = fuzz_files.outcome(path, case.loader)
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, old)
    assert result in ("loaded", "rejected"), (case.label, result, detail)
