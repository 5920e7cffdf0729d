"""Recording and replay (docs/recording.md): what the daemon writes, what a kill leaves,
and that replaying a recording gives the live results, float for float.

(Its tests with real peers: tests/system/test_recording.py.)
"""

from __future__ import annotations

import asyncio
import errno
import json
import logging
import math
import os
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from fluidsense import cli
from fluidsense.common.errors import ConfigError, EndOfRecording, RecordingError
from fluidsense.common.scenes import CylinderScene, EmptyScene
from fluidsense.controller.config import CellConfig, load_cell_config
from fluidsense.controller.cycles.reanalysis import REPRODUCIBLE, CycleReplay, _differences, comparable, replay_file
from fluidsense.controller.service import Sink
from fluidsense.controller.telemetry.queued import QueuedSink
from fluidsense.daemon import app
from fluidsense.drivers.recording.reader import RecordingReader
from fluidsense.drivers.recording.schema import (
    CONFIG,
    FORMAT,
    FORMAT_VERSION,
    SAMPLES,
    event_schema,
)
from fluidsense.drivers.recording.sink import new_path
from fluidsense.drivers.recording.writer import RecordingWriter
from mcap.reader import make_reader
from support.configs import whole
from support.cli import run_cli
from support.harness import REPO, sim_config
from support.recording import BOMBS, cell, record, the_file, with_chunk


async def varied_cycles(ctrl) -> list:
    """A reference, two objects, an aborted cycle, a held one, a sensor fault."""
    results = []
    await ctrl.scene.place(EmptyScene())
    results.append(await ctrl.run_cycle(store_reference=True))
    for d in (40, 80):
        await ctrl.scene.place(CylinderScene(diameter_mm=d))
        results.append(await ctrl.run_cycle(label=f"D{d}"))
    fut = await ctrl.start_cycle(label="aborted")
    await ctrl.wait(23.456)  # inside ACTUATE
    await ctrl.abort("test")
    results.append(await fut)
    fut = await ctrl.start_cycle(label="held", hold=True)
    await ctrl.measured()
    await ctrl.wait(3.0)
    results.append(await ctrl.release())
    fut = await ctrl.start_cycle(label="nan")
    ctrl.backend.sim.inject("sensor_nan", ctrl.now + 25.0)
    results.append(await fut)
    ctrl.backend.sim.clear_faults()
    ctrl.reset()
    results.append(await ctrl.run_cycle(label="after reset"))
    return results


def recording_sink(ctrl) -> QueuedSink:
    """The recording among the controller's sinks (the gripper watches the blocks too)."""
    (sink,) = [s for s in ctrl.telemetry.sinks if isinstance(s, QueuedSink)]
    return sink


@pytest.fixture(scope="module")
def varied(tmp_path_factory) -> tuple[CellConfig, list, Path]:
    """One recording of varied_cycles: its config, the live results, the file."""
    tmp = tmp_path_factory.mktemp("varied")
    cfg = cell(tmp)
    live = record(tmp, varied_cycles, cfg=cfg)
    return cfg, live, the_file(tmp)


@pytest.fixture(scope="module")
def good_file(tmp_path_factory) -> Path:
    """A short recording: a free-air reference and one object."""
    tmp = tmp_path_factory.mktemp("good")

    async def two(ctrl):
        await ctrl.run_cycle(store_reference=True)
        await ctrl.scene.place(CylinderScene(diameter_mm=60))
        await ctrl.run_cycle()

    record(tmp, two)
    return the_file(tmp)


# ----------------------------------------------------------------- replay = live
def test_replay_gives_the_live_results_float_for_float(varied):
    _, live, path = varied
    assert [r.ok for r in live] == [True, True, True, False, True, False, True]
    assert live[3].aborted == "test" and live[5].aborted == "fault: sensor_nan"
    assert live[2].has_reference and live[2].dp_eq is not None  # the reference path is exercised

    report = asyncio.run(replay_file(path))
    assert report.closed and report.dropped_bytes == 0 and report.agree
    assert [c.cycle_id for c in report.cycles] == [r.cycle_id for r in live]
    for cyc, res in zip(report.cycles, live):
        assert cyc.complete and cyc.agree, (cyc.cycle_id, cyc.differences)
        assert cyc.replay == comparable(res.to_dict())  # every field, exact floats
    # the NaN readings that faulted cycle 6 came back as NaN, not as numbers
    with RecordingReader(path) as reader:
        values = np.concatenate([r.data.values for r in reader.records() if r.topic == SAMPLES])
    assert np.isnan(values).any()


def test_the_comparison_sees_a_changed_pipeline(varied):
    """Replayed with other windows, the same records no longer agree: agreement above is
    not an artefact of copying the live results."""
    with RecordingReader(varied[2]) as reader:
        cfg = CellConfig.model_validate(reader.config)
        seq = cfg.profile.sequence
        other = seq.model_copy(update={"windows": [seq.windows[0].model_copy(update={"end_s": 4.9})]})
        pipeline = CycleReplay(other)
        for rec in reader.records():
            if rec.topic == SAMPLES:
                pipeline.on_block(rec.data)
            else:
                pipeline.on_event(rec)
    cycles = pipeline.finish()
    assert {c.cycle_id for c in cycles if c.agree is False} == {1, 2, 3, 5, 7}  # the ones with features
    assert "p_eq_kpa" in cycles[1].differences


def test_the_recording_holds_config_commands_and_events(varied):
    cfg, _, path = varied
    with RecordingReader(path) as reader:
        assert reader.metadata["format"] == "fluidsense-recording" and reader.metadata["rate_hz"] == "1000.0"
        assert CellConfig.model_validate(reader.config) == cfg  # the config round-trips exactly
        topics: dict[str, list] = {}
        for rec in reader.records():
            topics.setdefault(rec.topic, []).append(rec)
    assert {"samples", "state", "cycle", "heartbeat", "fault", "cycle_start", "command"} <= set(topics)
    blocks = [r.data for r in topics["samples"]]
    t = np.concatenate([b.t for b in blocks])
    assert np.all(np.diff(t) > 0) and blocks[0].channels == ("p_act", "p_tank")
    valves = [r.data for r in topics["command"] if r.data["kind"] == "valve"]
    assert {"valve": "actuate", "open": True, "kind": "valve", "t_s": topics["state"][2].data["at_s"]} in valves
    assert [r.data["p0_pa"] for r in topics["cycle_start"]] == [63e3] * 7


# ----------------------------------------------------------------- the flush guarantee
def test_what_is_on_disk_lags_sample_time_by_at_most_flush_s(tmp_path):
    """A SIGKILL loses what the process had not yet handed to the OS: the file as it is on
    disk at any moment. Read it at odd moments of a cycle, without closing the writer."""
    seen = []

    async def body(ctrl):
        sink = recording_sink(ctrl)
        fut = await ctrl.start_cycle()
        for step in (0.35, 1.73, 0.011, 2.5, 13.0, 0.99, 7.77):
            await ctrl.wait(step)
            sink.wait_idle()  # the writer thread has what the loop handed it (normally within ms)
            copy = tmp_path / f"at-{ctrl.now:.3f}.mcap"
            shutil.copyfile(sink.inner.path, copy)
            with RecordingReader(copy) as reader:
                last = max((r.t_s for r in reader.records() if r.topic == SAMPLES), default=0.0)
                seen.append((ctrl.now, last, reader.complete))
        await fut

    record(tmp_path, body, flush_s=1.0)
    for now, last, complete in seen:
        assert not complete
        assert now - 1.0 - 0.010 - 1e-9 <= last <= now, (now, last)  # flush_s plus one block at most
    assert any(now - last > 0.5 for now, last, _ in seen)  # and something really was still unflushed


def test_every_cut_of_a_file_reads_up_to_the_cut(tmp_path, good_file):
    """Wherever a file is cut, what is left reads (or says clearly that nothing can):
    blocks are a prefix of the full recording and complete cycles still agree."""
    full = good_file
    data = full.read_bytes()
    with RecordingReader(full) as reader:
        all_t = [r.t_s for r in reader.records() if r.topic == SAMPLES]
    last_before = -1.0
    for frac in np.linspace(0.0, 0.999, 17):
        cut = tmp_path / "cut.mcap"
        cut.write_bytes(data[: int(len(data) * frac)])
        try:
            report = asyncio.run(replay_file(cut))
        except RecordingError as exc:
            assert str(exc).startswith(f"{cut}: ") and frac < 0.01, (frac, exc)
            continue
        assert not report.closed and report.agree
        assert report.blocks == 0 or report.t_last_s == all_t[report.blocks - 1]
        t_last = report.t_last_s or 0.0
        assert t_last >= last_before
        last_before = t_last
    assert last_before > all_t[-1] - 5  # the late cuts keep nearly everything


# ----------------------------------------------------------------- bad files
def _not_ours(path: Path) -> None:
    from mcap.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("x", "jsonschema", b"{}")
        cid = w.register_channel("/config", "json", sid)
        w.add_message(cid, log_time=0, data=b"{}", publish_time=0)
        w.finish()


def _flip(path: Path, good: Path) -> None:
    """One bit of rot in the compressed records of a chunk in the middle of the file."""
    data = bytearray(good.read_bytes())
    chunks, pos = [], 8
    while pos < len(data) and data[pos] != 0x0F:  # top-level records up to the footer
        length = struct.unpack_from("<Q", data, pos + 1)[0]
        if data[pos] == 0x06:  # a chunk: its compressed records are its last bytes
            chunks.append(pos + 9 + length)
        pos += 9 + length
    end = chunks[len(chunks) // 2]
    data[end - 100] ^= 0x10
    path.write_bytes(bytes(data))


BAD = {
    "empty": (lambda p, g: p.write_bytes(b""), "cut off after 0 bytes, before its cell config"),
    "text": (lambda p, g: p.write_text("driver: {kind: sim}\n"), "not an MCAP file"),
    "header only": (lambda p, g: p.write_bytes(g.read_bytes()[:40]), "before its cell config"),
    "flipped byte": (_flip, "garbled near byte"),
    "other mcap": (lambda p, g: _not_ours(p), "not a fluidsense recording"),
    "missing": (lambda p, g: None, "cannot read: No such file"),
}


@pytest.mark.parametrize("kind", BAD)
def test_a_bad_file_gives_one_clear_error_naming_it(tmp_path, good_file, kind, capsys):
    make, reason = BAD[kind]
    path = tmp_path / f"{kind.replace(' ', '-')}.mcap"
    make(path, good_file)
    with pytest.raises(RecordingError) as err:
        asyncio.run(replay_file(path))
    msg = str(err.value)
    assert msg.startswith(f"{path}: ") and reason in msg and "\n" not in msg
    if kind in ("text", "flipped byte", "missing"):
        assert err.value.__cause__ is not None
    assert cli.main(["replay", str(path)]) == 2  # the exit code (a subprocess below checks one)
    out = capsys.readouterr()
    assert out.out == "" and out.err.splitlines() == [f"fluidsense: error: {msg}"]


def test_a_recorded_config_that_no_longer_validates_names_the_file(tmp_path):
    path = tmp_path / "bad-config.mcap"
    w = RecordingWriter(path, 0)
    w.write_config({"driver": {"kind": "sim"}, "profile": {"name": "p"}, "colour": 3}, {})
    w.close()
    with pytest.raises(ConfigError, match=rf"^{path}: \(recorded config\) colour: unknown field"):
        asyncio.run(replay_file(path))


# ----------------------------------------------------------------- the CLI
def _copy_with(src: Path, dst: Path, change) -> None:
    """Rewrite a recording record by record, letting ``change`` edit event payloads."""
    with RecordingReader(src) as reader:
        w = RecordingWriter(dst, 0, {k: v for k, v in reader.metadata.items() if k in ("rate_hz", "channels")})
        w.write_config(reader.config, {})
        for rec in reader.records():
            if rec.topic == SAMPLES:
                w.write_block(rec.data)
            elif rec.topic != CONFIG:
                payload = {k: v for k, v in rec.data.items() if k != "t_s"}
                w.write_event(rec.topic, rec.t_s, change(rec.topic, payload))
        w.close()


def test_cli_replay_json_and_exit_codes(tmp_path, good_file, capsys):
    out = run_cli(capsys, "replay", good_file, "--json", cwd=REPO)
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    assert doc["agree"] and doc["closed"] and [c["status"] for c in doc["cycles"]] == ["complete"] * 2
    assert doc["cycles"][1]["replay"]["p_eq_kpa"] == doc["cycles"][1]["live"]["p_eq_kpa"]

    def nudge(topic, payload):
        if topic == "cycle" and payload["cycle_id"] == 2:
            payload = {**payload, "p_eq_kpa": payload["p_eq_kpa"] + 1e-6}  # 1 mPa: 1/16000 of a sensor quantum
        return payload

    tampered = tmp_path / "tampered.mcap"
    _copy_with(good_file, tampered, nudge)
    out = run_cli(capsys, "replay", tampered, cwd=REPO)
    assert out.returncode == 1, out.stderr
    assert "differs in: p_eq_kpa" in out.stdout and "cycles [2] differ" in out.stdout

    garbled = tmp_path / "garbled.mcap"
    _flip(garbled, good_file)
    out = run_cli(capsys, "replay", garbled, cwd=REPO)
    assert out.returncode == 2 and out.stdout == ""
    assert len(out.stderr.splitlines()) == 1 and out.stderr.startswith(f"fluidsense: error: {garbled}: garbled")


# ----------------------------------------------------------------- files, rotation, failures
def test_files_are_never_overwritten(tmp_path):
    first = new_path(tmp_path)
    first.write_bytes(b"keep")
    second = new_path(tmp_path)
    assert second != first and second.name.startswith(first.stem)
    with pytest.raises(FileExistsError):
        RecordingWriter(first, 0)
    assert first.read_bytes() == b"keep"
    second.write_bytes(b"")
    third = new_path(tmp_path)
    assert sorted([third, second, first]) == [first, second, third]  # name order = write order


def test_rotation_between_cycles_keeps_every_file_replayable(tmp_path):
    async def body(ctrl):
        await ctrl.run_cycle(store_reference=True)
        await ctrl.scene.place(CylinderScene(diameter_mm=70))
        return [await ctrl.run_cycle() for _ in range(3)]

    live = record(tmp_path, body, max_file_mb=0.2)
    files = sorted((tmp_path / "runs").glob("*.mcap"))
    assert len(files) == 4
    replayed = []
    for f in files:
        report = asyncio.run(replay_file(f))
        assert report.closed and report.agree and len(report.cycles) == 1
        replayed += report.cycles
    assert [c.cycle_id for c in replayed] == [1, 2, 3, 4]  # each cycle whole, in one file
    for c, res in zip(replayed[1:], live):
        assert c.replay["has_reference"] and c.replay == comparable(res.to_dict())  # the reference travelled


def test_files_rotate_by_sample_time_between_cycles(tmp_path):
    """max_file_s bounds what one file covers, hence the writer's in-memory index (the soak
    found +28 MB over 8 h in one file)."""
    async def body(ctrl):
        return [await ctrl.run_cycle(store_reference=True)] + [await ctrl.run_cycle() for _ in range(4)]

    live = record(tmp_path, body, max_file_s=60.0)
    starts = {r.cycle_id: r.t_start for r in live}
    files = sorted((tmp_path / "runs").glob("*.mcap"))
    assert len(files) >= 2
    ids = []
    for f in files:
        report = asyncio.run(replay_file(f))
        assert report.closed and report.agree
        cids = [c.cycle_id for c in report.cycles]
        ids += cids
        assert starts[cids[-1]] - starts[cids[0]] < 60.0, (f.name, cids)  # no cycle started past the limit
    assert ids == [1, 2, 3, 4, 5]  # each cycle whole, in one file, in order


def test_a_write_error_drops_the_recording_and_control_goes_on(tmp_path, caplog):
    def disk_full():
        raise OSError(errno.ENOSPC, "No space left on device")

    async def body(ctrl):
        queued = recording_sink(ctrl)
        await ctrl.wait(30.0)
        queued.wait_idle()
        sink = queued.inner
        sink._writer.flush = disk_full
        res = await ctrl.run_cycle()
        return sink, res

    with caplog.at_level(logging.ERROR):
        sink, res = record(tmp_path, body)
    assert res.ok  # the cycle ran to its end without the recording
    assert any("dropped" in r.message and str(sink.path) in r.message and "No space left" in r.message
               for r in caplog.records)
    with RecordingReader(sink.path) as reader:  # what was flushed before the error is there
        last = max(r.t_s for r in reader.records() if r.topic == SAMPLES)
    assert 29.0 <= last <= 31.0


def test_a_nearly_full_disk_stops_the_recording_and_says_so(tmp_path, monkeypatch, caplog):
    (tmp_path / "second").mkdir()
    with pytest.raises(ConfigError, match=r"recording.dir: cannot record in .*MB free"):
        record(tmp_path, lambda ctrl: ctrl.wait(1.0), min_free_mb=1_000_000)

    real = shutil.disk_usage

    logs: list[dict] = []

    class Logs(Sink):
        def on_event(self, topic, t_s, payload):
            if topic == "log":
                logs.append(payload)

    async def body(ctrl):
        ctrl.add_sink(Logs())
        await ctrl.wait(5.0)
        monkeypatch.setattr("fluidsense.drivers.recording.sink.shutil.disk_usage",
                            lambda p: real(p)._replace(free=10 * 2**20))
        await ctrl.run_cycle()
        return ctrl.telemetry.sinks, ctrl.status()

    with caplog.at_level(logging.ERROR):
        sinks, status = record(tmp_path / "second", body)
    assert not any(isinstance(s, QueuedSink) for s in sinks)  # the recording was dropped
    assert any("MB free" in r.message and "recording stopped" in r.message for r in caplog.records)
    # ... and the operator sees it: status keeps it as failed, with the reason; a log event (ERROR) says so
    (failed,) = status["sinks"]
    assert failed["sink"] == "RecordingSink" and failed["state"] == "failed", failed
    assert "MB free" in failed["reason"] and failed["t_s"] > 5.0, failed
    (said,) = [e for e in logs if e.get("sink") == "RecordingSink"]
    assert said["level"] == "ERROR" and "MB free" in said["message"], said
    with RecordingReader(the_file(tmp_path / "second")) as reader:
        list(reader.records())
        assert reader.complete  # closed properly before stopping


def test_run_record_and_no_record_flags(tmp_path, monkeypatch):
    from fluidsense.cli import build_parser
    from fluidsense.cli.subcommands import run as run_cmd
    from fluidsense.daemon import app

    seen = []

    async def fake_daemon(cfg, tasks_dir, own_process):
        seen.append(cfg.recording)
        return 0

    monkeypatch.setattr(app, "run_daemon", fake_daemon)
    path = str(sim_config(tmp_path))
    for extra in ([], ["--no-record"], ["--record", str(tmp_path / "elsewhere")]):
        assert run_cmd.main(build_parser().parse_args(["run", "--config", path, *extra])) == 0
    default, off, moved = seen
    assert default.enabled and default.dir == str(tmp_path / "runs")
    assert not off.enabled
    assert moved.enabled and moved.dir == str(tmp_path / "elsewhere")
    with pytest.raises(SystemExit):
        build_parser().parse_args(["run", "--record", "x", "--no-record"])


class Probe(Sink):
    def __init__(self):
        self.blocks = []

    def on_block(self, block) -> None:
        self.blocks.append(block)


# ----------------------------------------------------------------- the replay driver
def test_replay_driver_feeds_the_recorded_blocks_to_a_controller(tmp_path, good_file):
    with RecordingReader(good_file) as reader:
        recorded = [r.data for r in reader.records() if r.topic == SAMPLES]
    cfg = load_cell_config(sim_config(tmp_path, driver=whole({"kind": "replay", "file": str(good_file)})))

    async def main():
        async with app.controller(cfg) as ctrl:
            assert ctrl.virtual and ctrl.backend.source.rate_hz == 1000.0
            probe = Probe()
            ctrl.add_sink(probe)
            await ctrl.wait(12.345)
            return ctrl.now, probe.blocks

    now, seen = asyncio.run(main())
    assert now == recorded[len(seen) - 1].t_end and 12.345 <= now < 12.36
    for got, want in zip(seen, recorded):
        assert got.seq == want.seq and np.array_equal(got.t, want.t) and np.array_equal(got.values, want.values)

    async def drain():
        from fluidsense.drivers.recording.backend import ReplaySource

        async with ReplaySource(good_file) as src:
            n = 0
            while True:
                try:
                    await src.read_block()
                except EndOfRecording as exc:
                    return n, str(exc)
                n += 1

    n, msg = asyncio.run(drain())
    assert n == len(recorded) and msg.startswith(f"{good_file}: end of the recording at t = ")


# ----------------------------------------------------------------- hostile recordings (issue 14, item 5)
# (the bombs: tests/support/recording.py)




@pytest.mark.parametrize("kind", BOMBS)
def test_a_decompression_bomb_is_refused_within_bounds(tmp_path, good_file, kind):
    make, reason = BOMBS[kind]
    path = tmp_path / "bomb.mcap"
    with_chunk(path, good_file, make())
    with pytest.raises(RecordingError) as err:
        asyncio.run(replay_file(path))
    msg = str(err.value)
    assert msg.startswith(f"{path}: garbled near byte ") and msg.endswith(reason) and "\n" not in msg, msg


def _events(change):
    """A `_copy_with` change that edits one topic's payloads."""
    def edit(topic, payload):
        return change(payload) if topic == edit.topic else payload
    return edit


NULLS = {
    "cycle_start.p0_pa": ("cycle_start", lambda p: {**p, "p0_pa": None}, "cycle_start.p0_pa: expected a finite "
                          "number, got None"),
    "state.reason": ("state", lambda p: {**p, "reason": None}, "state.reason: expected a string, got None"),
    "state.at_s": ("state", lambda p: {**p, "at_s": "soon"}, "state.at_s: expected a finite number, got soon"),
    "cycle_start.store_reference": ("cycle_start", lambda p: {**p, "store_reference": 1},
                                    "cycle_start.store_reference: expected true or false, got 1"),
}


@pytest.mark.parametrize("field", NULLS)
def test_a_recorded_event_without_what_replay_reads_names_topic_and_field(tmp_path, good_file, field):
    topic, change, reason = NULLS[field]
    edit = _events(change)
    edit.topic = topic
    path = tmp_path / "null.mcap"
    _copy_with(good_file, path, edit)
    with pytest.raises(RecordingError) as err:
        asyncio.run(replay_file(path))
    assert str(err.value).startswith(f"{path}: {reason} (at t = "), str(err.value)


def _rewrite_samples(src: Path, dst: Path, change) -> None:
    with RecordingReader(src) as reader:
        w = RecordingWriter(dst, 0, {k: v for k, v in reader.metadata.items() if k in ("rate_hz", "channels")})
        w.write_config(reader.config, {})
        for rec in reader.records():
            if rec.topic == SAMPLES:
                from fluidsense.drivers.recording.messages import block_payload

                w._add(SAMPLES, rec.t_s, json.dumps(change(block_payload(rec.data))).encode(), {})
        w.close()


@pytest.mark.parametrize("change, reason", [
    (lambda p: {**p, "times_s": [None] * len(p["times_s"])}, "ValueError: times_s: expected increasing finite sample "
                                                             "times"),
    (lambda p: {**p, "values": p["values"][:1]}, "ValueError: values: expected 2 rows of 10, got shape (1, 10)"),
    (lambda p: {**p, "seq": -1}, "ValueError: seq: expected a count, got -1"),
    (lambda p: {**p, "channels": "p_act"}, "ValueError: channels: expected a list of names"),
    (lambda p: {**p, "values": json.loads("[" * 40 + "]" * 40)}, "ValueError: values: expected 2 rows"),
])
def test_a_garbled_sample_block_names_its_field(tmp_path, good_file, change, reason):
    path = tmp_path / "samples.mcap"
    _rewrite_samples(good_file, path, change)
    with pytest.raises(RecordingError) as err:
        asyncio.run(replay_file(path))
    msg = str(err.value)
    assert msg.startswith(f"{path}: garbled message on samples near byte ") and reason in msg and "\n" not in msg


@pytest.mark.parametrize("depth, reason", [(100, "nested more than 32 levels deep"),
                                           (100_000, "RecursionError: maximum recursion depth exceeded")])
def test_deeply_nested_json_in_an_event_is_refused(tmp_path, good_file, depth, reason):
    path = tmp_path / "deep.mcap"
    with RecordingReader(good_file) as reader:
        w = RecordingWriter(path, 0, {k: v for k, v in reader.metadata.items() if k in ("rate_hz", "channels")})
        w.write_config(reader.config, {})
    w._add("state", 0.0, b'{"t_s": 0, "x": ' + b"[" * depth + b"]" * depth + b"}", {})
    w.close()
    with pytest.raises(RecordingError) as err:
        asyncio.run(replay_file(path))
    msg = str(err.value)
    assert msg.startswith(f"{path}: garbled message on state near byte ") and reason in msg and "\n" not in msg


@pytest.mark.parametrize("kind", ["fifo", "directory"])
def test_replay_refuses_a_fifo_or_a_directory_without_blocking(tmp_path, kind, capsys):
    path = tmp_path / "run.mcap"
    os.mkfifo(path) if kind == "fifo" else path.mkdir()
    out = run_cli(capsys, "replay", path, cwd=REPO)  # a blocking open would hang it: the tier's timeout
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.splitlines() == [f"fluidsense: error: {path}: cannot read: not a regular file "
                                       f"(a {'FIFO' if kind == 'fifo' else 'directory'})"]


FORMAT_1 = REPO / "tests" / "data" / "recording-format-1.mcap"


def test_a_recording_written_before_the_move_reads_and_replays_the_same():
    """tests/data/recording-format-1.mcap was written by the daemon's recording at commit
    6934979, before the format moved into drivers/recording/ (a simulated cell at 200 Hz in
    virtual time, seed 3, the gripper's 3.5 s cycle: a free-air reference, then a 60 mm
    cylinder). Files on disk must stay readable: its channels keep their schema names
    (``fluidsense.Command`` ...), its cycles replay to their recorded results."""
    report = asyncio.run(replay_file(FORMAT_1))
    assert report.closed and report.agree and report.samples == 1705
    assert [(c.label, c.complete, c.agree) for c in report.cycles] == [("free", True, True), ("c60", True, True)]
    with RecordingReader(FORMAT_1) as rec:
        assert (rec.metadata["format"], rec.metadata["format_version"]) == (FORMAT, str(FORMAT_VERSION))
    with FORMAT_1.open("rb") as f:
        summary = make_reader(f).get_summary()
    names = {ch.topic.removeprefix("/"): summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
    assert names.pop(CONFIG) == "CellConfig"
    assert names == {topic: event_schema(topic)["title"] for topic in names}  # what the writer registers today
    assert {"samples", "command", "cycle_start", "state", "cycle", "heartbeat"} <= set(names)
    assert names["command"] == "fluidsense.Command" and names["samples"] == "fluidsense.SampleBlock"


def test_a_replayed_number_off_in_its_last_bits_agrees_and_a_changed_one_does_not():
    """tests/data/recording-format-1.mcap's contact time replays on an AVX2 kernel one
    ulp from the recorded one (another CPU sums and interpolates in another order): the
    same result. A change the pipeline could make (here 1e-6 relative, far under a sensor
    quantum) is a difference, at the top level and inside a window."""
    live = {"t_s": 1.0, "t_c_threshold_s": 0.15123473920597566, "p_eq_kpa": 34.6, "label": "c60",
            "windows": [{"name": "eq", "mean_kpa": 34.6}]}
    ulp = {**live, "t_c_threshold_s": 0.15123473920597563,
           "windows": [{"name": "eq", "mean_kpa": math.nextafter(34.6, 40.0)}]}
    assert _differences(ulp, live) == []
    moved = {**live, "t_c_threshold_s": live["t_c_threshold_s"] * (1 + 1e3 * REPRODUCIBLE)}
    assert _differences(moved, live) == ["t_c_threshold_s"]
    window = {**live, "windows": [{"name": "eq", "mean_kpa": 34.6 * (1 + 1e3 * REPRODUCIBLE)}]}
    assert _differences(window, live) == ["windows"]
    assert _differences({**live, "p_eq_kpa": None}, live) == ["p_eq_kpa"]
    assert _differences({**live, "label": "c40"}, live) == ["label"]
