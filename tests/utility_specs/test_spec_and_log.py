"""Mission specs and logs: the shipped specs load, bad ones fail naming file, key, expectation."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from utility_specs.errors import LogError, SpecError
from utility_specs.files import builtin_spec, builtin_specs, load_spec, read_log
from utility_specs.log import message_to_record, parse_log, write_record
from utility_specs.message import Message, Version

EXPECTED_SPECS = {"image_streaming", "kpk_reconstruction", "telemetry", "sim_mostly_low",
                  "sim_uniform", "sim_mostly_high"}


def test_the_shipped_specs_load() -> None:
    assert set(builtin_specs()) >= EXPECTED_SPECS
    for name in builtin_specs():
        spec = builtin_spec(name)
        assert spec.types
    image = builtin_spec("image_streaming")["image"]
    assert image.utility.name == "red_image" and image.per_sender


@pytest.mark.parametrize(
    "name,weight",
    [("sim_mostly_low", lambda i: 3 ** (i + 1)), ("sim_uniform", lambda i: 1000 * i + 1),
     ("sim_mostly_high", lambda i: i**0.1 + 1)],
)
def test_simulation_scenario_weights(name, weight) -> None:  # type: ignore[no-untyped-def]
    spec = builtin_spec(name)
    assert [spec[f"battery_{i}"].weight for i in range(10)] == pytest.approx(
        [weight(i) for i in range(10)]
    )


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "body,fragment",
    [
        ('[types.b]\nutility = "battery"\naggregation = "avg"\n', "types.b.aggregation: expected"),
        ('[types.b]\nutility = "nope"\naggregation = "max"\n', "unknown utility 'nope'"),
        ('[types.b]\nutility = "battery"\naggregation = "max"\nweight = -1\n', "types.b.weight"),
        ('[types.b]\nutility = "battery"\naggregation = "max"\nparams = { depletion_rate = "x" }\n',
         "depletion_rate"),
        ('[types.b]\nutility = "battery"\naggregation = "max"\nper_sender = 1\n',
         "types.b.per_sender: expected true or false"),
        ('[types.b]\nutility = "external"\naggregation = "max"\n', "supports aggregation"),
        ('[types.b]\nutility = "battery"\naggregation = "max"\ncolour = 1\n', "types.b.colour"),
        ("[mission]\nname = 1\n", "mission.name"),
        ("[types\n", "not valid TOML"),
    ],
)
def test_a_wrong_spec_names_file_key_and_expectation(tmp_path, body, fragment) -> None:  # type: ignore[no-untyped-def]
    path = _write(tmp_path, body)
    with pytest.raises(SpecError) as info:
        load_spec(path)
    assert str(path) in str(info.value)
    assert fragment in str(info.value)


def test_log_round_trip_with_versions_and_states() -> None:
    versions = (Version(name="full", size=100, quality=1.0), Version(name="half", size=40,
                                                                       quality=0.5))
    m = Message(sender="d1", receiver="gs", seq=3, type="image", t_gen=1.0, t_sent=1.1,
                t_rcv=1.5, size=40, data={"red": 0.2}, versions=versions, version=1)
    lines = []

    class Sink:
        def write(self, text: str) -> None:
            lines.append(text)

    write_record(Sink(), message_to_record(m, decision={"send": True}))  # type: ignore[arg-type]
    lines.append(json.dumps({"state": {"agent": "gs", "t": 0.5, "objectives": ["o1"]}}))
    lines.append(json.dumps({"mission": {"t_start": 0.0, "t_end": 10.0}}))
    log = parse_log(lines)
    assert log.messages == [m]
    assert log.t_end == 10.0 and log.t_start == 0.0
    assert log.states["gs"].at(1.0) == {"objectives": ["o1"]}
    assert log.states["gs"].at(0.0) == {}


@pytest.mark.parametrize(
    "line,fragment",
    [("{not json", "x.jsonl:2"), ('{"sender": "a"}', "missing key 'seq'"),
     ('{"sender": "a", "seq": 1, "type": "t", "t_gen": 5, "t_rcv": 1}', "before t_gen"),
     ('{"state": {"t": 1}}', "agent")],
)
def test_a_bad_log_line_names_the_line(line, fragment) -> None:  # type: ignore[no-untyped-def]
    good = '{"mission": {"t_end": 5}}'
    with pytest.raises(LogError, match=fragment.replace("(", r"\(")):
        parse_log([good, line], source="x.jsonl")


def test_a_torn_last_line_is_skipped_and_reported(tmp_path: Path) -> None:
    """A writer that stopped mid-line (crash, power loss) leaves an unterminated last line;
    the complete records before it still count. A bad line with its newline stays an error."""
    record = {"sender": "d1", "receiver": "gs", "seq": 0, "type": "battery", "t_gen": 0.0,
              "t_rcv": 0.5, "data": {"level": 1.0}}
    path = tmp_path / "log.jsonl"
    path.write_text(json.dumps(record) + "\n" + '{"mission": {"t_end": 10}}\n'
                    + json.dumps({**record, "seq": 1})[:40])
    log = read_log(path)
    assert [m.seq for m in log.messages] == [0] and log.t_end == 10.0
    assert log.torn_last_line == 3
    result = _run("evaluate", "--spec", "telemetry", "--json", str(path))
    assert result.returncode == 0, result.stderr
    assert f"{path}:3: incomplete last line ignored" in result.stderr
    assert json.loads(result.stdout)["total"] == pytest.approx(9.5 - 0.5 + 0.00125)
    # complete (terminated) bad lines are errors; so is a torn line that is not the last
    path.write_text(json.dumps(record)[:40] + "\n" + '{"mission": {"t_end": 10}}\n')
    with pytest.raises(LogError, match=r"log\.jsonl:1"):
        read_log(path)
    # an unterminated last line that parses is a record like any other
    path.write_text('{"mission": {"t_end": 10}}\n' + json.dumps(record))
    assert read_log(path).torn_last_line is None and len(read_log(path).messages) == 1


def test_missing_log_file() -> None:
    with pytest.raises(LogError, match="no such log file"):
        read_log("/nonexistent/log.jsonl")


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "utility_specs.cli", *args],
                          capture_output=True, text=True, timeout=120)


def test_cli_evaluate_json_merges_sender_and_receiver_logs(tmp_path: Path) -> None:
    sent = tmp_path / "drone.jsonl"
    got = tmp_path / "gs.jsonl"
    sent.write_text("\n".join(json.dumps(r) for r in [
        {"sender": "d1", "receiver": None, "seq": 0, "type": "battery", "t_gen": 0.0,
         "t_sent": 0.0, "t_rcv": None, "size": 10, "data": {"level": 1.0}},
        {"sender": "d1", "receiver": None, "seq": 1, "type": "battery", "t_gen": 5.0,
         "t_sent": 5.0, "t_rcv": None, "size": 10, "data": {"level": 1.0}},
    ]) + "\n")
    got.write_text("\n".join(json.dumps(r) for r in [
        {"mission": {"t_end": 10.0}},
        {"sender": "d1", "receiver": "gs", "seq": 0, "type": "battery", "t_gen": 0.0,
         "t_sent": 0.0, "t_rcv": 0.0, "size": 10, "data": {"level": 1.0}},
    ]) + "\n")
    result = _run("evaluate", "--spec", "telemetry", "--json", str(sent), str(got))
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    # battery at 0.01/s from a full level: ∫_0^10 (1 - 0.01 t) dt = 9.5
    assert out["total"] == pytest.approx(9.5)
    assert out["per_type"]["battery"] == pytest.approx(9.5)
    assert out["per_receiver"] == {"gs": pytest.approx(9.5)}


def test_cli_reports_errors_without_a_traceback(tmp_path: Path) -> None:
    log = tmp_path / "log.jsonl"
    log.write_text('{"sender": "d1", "seq": 0, "type": "nope", "t_gen": 0, "t_rcv": 1, '
                   '"receiver": "gs"}\n{"mission": {"t_end": 3}}\n')
    result = _run("evaluate", "--spec", "telemetry", str(log))
    assert result.returncode == 2
    assert "error" in result.stderr and "'nope'" in result.stderr
    assert "Traceback" not in result.stderr


def test_cli_reads_an_existing_spec_file_whatever_its_suffix(tmp_path: Path) -> None:
    """``--spec /tmp/spec.txt`` (a TOML file) said "no built-in spec '/tmp/spec.txt'"."""
    spec = tmp_path / "spec.txt"
    spec.write_text((Path(__file__).parents[2] / "utility_specs" / "missions" /
                     "telemetry.toml").read_text())
    log = tmp_path / "log.jsonl"
    log.write_text('{"mission": {"t_end": 3}}\n')
    result = _run("evaluate", "--spec", str(spec), "--json", str(log))
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["total"] == 0
    missing = _run("evaluate", "--spec", str(tmp_path / "no" / "spec.txt"), str(log))
    assert missing.returncode == 2 and "Traceback" not in missing.stderr
    assert missing.stderr.strip() == (f"uav-utility: error: {tmp_path}/no/spec.txt: "
                                      "no such spec file")


def test_cli_plot_writes_a_png(tmp_path: Path) -> None:
    out = tmp_path / "fig.png"
    result = _run("plot", "4.9", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
