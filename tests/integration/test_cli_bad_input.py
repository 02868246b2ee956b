"""Bad input to any console script is one line on stderr and a non-zero exit, never a
traceback (issue 13, item 7), and a bad URL never makes the ground station answer 500."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from tests.keys import write_test_keys
from tests.processes import assert_one_line_error

BIN = Path(sys.executable).parent
DEEP = 50_000  # well past Python's recursion limit


def _tool(name: str) -> str:
    path = BIN / name
    if not path.exists():
        pytest.skip(f"{name} is not installed in this environment (pip install -e .)")
    return str(path)


@pytest.fixture(scope="module")
def bad(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("bad")
    files = {
        "binary": root / "binary.toml",
        "deep_toml": root / "deep.toml",
        "deep_jsonl": root / "deep.jsonl",
        "a_file": root / "a_file",
        "folder": root / "folder",
        "long_id": root / "long_id.toml",
        "port": root / "port.toml",
        "no_db": root / "no_db",
        "keyed": root / "keyed.toml",
        "keyed_companion": root / "keyed_companion.toml",
    }
    files["binary"].write_bytes(bytes(range(256)) * 4)
    files["deep_toml"].write_text("a = " + "[" * DEEP + "]" * DEEP + "\n")
    files["deep_jsonl"].write_text('{"sender": ' + "[" * DEEP + "]" * DEEP + "}\n")
    files["a_file"].write_text("not a folder\n")
    files["folder"].mkdir()
    files["long_id"].write_text(f'[drone]\nid = "{"d" * 40}"\n')
    files["typo"] = root / "typo.toml"
    files["typo"].write_text('[drone]\nid = "d1"\n[mavlink]\nulr = "udpin:127.0.0.1:14550"\n')
    files["port"].write_text('[drone]\nid = "d1"\n[mavlink]\nurl = "udpin:0.0.0.0:99999"\n')
    # The station has no built-in key: runs that are about something else get the test keys.
    write_test_keys(root / "keys")
    files["keyed"].write_text('[ground_station]\nfleet_key_file = "keys/fleet.key"\n'
                              'command_key_file = "keys/command.key"\n')
    files["keyed_companion"].write_text(
        '[drone]\nid = "d1"\n[ground_station]\nfleet_key_file = "keys/fleet.key"\n'
        'command_public_key_file = "keys/command.pub"\n')
    files["unwritable_log"] = root / "unwritable_log.toml"
    files["unwritable_log"].write_text(
        files["keyed_companion"].read_text()
        + f'[mission]\nlog = "{files["a_file"]}/mission.jsonl"\n[camera]\nenabled = false\n'
        '[mavlink]\nurl = "udpout:127.0.0.1:9"\n')
    return files


# (script, argv with {placeholders}, exit code, a fragment of the one-line error)
CASES = [
    ("uav-companion", "check --config {binary}", 2, "not a text file (byte 128 is not UTF-8)"),
    ("uav-companion", "run --config {binary}", 2, "not a text file"),
    ("uav-companion", "check --config {deep_toml}", 2, "nested too deeply"),
    ("uav-companion", "check --config {folder}", 2, "is a folder, not a configuration file"),
    ("uav-companion", "check --config {port}", 2,
     "mavlink.url: expected a pymavlink URL"),
    ("uav-companion", "run --config {port}", 2, "mavlink.url: expected a pymavlink URL"),
    ("uav-companion", "check --config {long_id} --skip-mavlink --skip-camera", 2,
     "drone.id: expected a printable sender id of 1..32 UTF-8 bytes"),
    ("uav-companion", "check --config {typo}", 2,
     "typo.toml: mavlink.ulr: expected a known key (did you mean 'url'?), one of ['baud', "),
    ("uav-companion", "run --config {long_id}", 2,
     "drone.id: expected a printable sender id of 1..32 UTF-8 bytes"),
    # run ended in a FileExistsError traceback; check had said "check: ok"
    ("uav-companion", "run --config {unwritable_log}", 2,
     "mission.log: cannot write {a_file}/mission.jsonl: File exists"),
    ("uav-companion", "check --config {unwritable_log} --skip-mavlink --skip-camera", 2,
     "mission.log: cannot write {a_file}/mission.jsonl: File exists"),
    ("uav-companion", "install-service --dry-run --config {binary}", 2, "not a text file"),
    ("uav-companion", "install-service --dry-run --user a:b --config {binary}", 2,
     "argument --user: expected a user name like pi, got 'a:b'"),
    ("uav-companion", "install-service --no-enable --user nosuchuser0 --unit-dir {folder} "
     "--config {keyed_companion}", 1, "no user 'nosuchuser0' on this machine"),
    # keys only root can read (the test's folders are 0700): the service failed at each start
    ("uav-companion", "install-service --no-enable --user nobody --unit-dir {folder} "
     "--config {keyed_companion}", 1, "install-service failed: user nobody cannot read "),
    ("uav-ground-station", "run --config {keyed} --data-dir {a_file} --udp-port 0 --http-port 0",
     2, "is a file, not a folder"),
    ("uav-ground-station",
     "run --config {keyed} --data-dir /proc/uav-gs-data --udp-port 0 --http-port 0", 2,
     "data dir /proc/uav-gs-data: not writable"),
    ("uav-ground-station", "token --data-dir {a_file}", 2, "is a file, not a folder"),
    # said "configuration error: <config>: key 'udp_port': ...": the value came from the option
    ("uav-ground-station", "run --config {keyed} --data-dir {folder}/gs --udp-port 99999", 2,
     "uav-ground-station: error: --udp-port: expected a port 0..65535, got 99999"),
    ("uav-ground-station", "run --config {keyed} --data-dir {folder}/gs --http-port -3", 2,
     "uav-ground-station: error: --http-port: expected a port 0..65535, got -3"),
    # printed http://127.0.0.1:0/?login=... (and made a token) for run's "any free port"
    ("uav-ground-station", "token --url --http-port 0 --data-dir {no_db}", 2,
     "token --url needs the dashboard's real port: give the --http-port that `run` printed"),
    ("uav-ground-station", "run --config {binary}", 2, "a UTF-8 TOML text file"),
    ("uav-ground-station", "run --config {deep_toml}", 2, "nested too deeply"),
    ("uav-ground-station", "run --config {folder}", 2, "a readable TOML file"),
    ("uav-ground-station", "export m1 --data-dir {no_db} --out {folder}/x", 1,
     "no ground station database in"),
    ("uav-ground-station", "export m1 --data-dir {folder} --out {folder}/x", 1,
     "no ground station database in"),
    ("uav-sitl", "vehicle --scene {binary} --duration 1", 2, "not a text file"),
    ("uav-sitl", "vehicle --scene {deep_toml} --duration 1", 2, "nested too deeply"),
    ("uav-sitl", "vehicle --port 99999", 2, "--port must be in 0..65535"),
    ("uav-sitl", "vehicle --speedup 0", 2, "--speedup must be > 0"),
    # each was a traceback (sysid, --out port: one per send, exit 0) or, for --speedup inf,
    # a vehicle spinning a core and deaf to SIGTERM
    ("uav-sitl", "vehicle --speedup inf --duration 1", 2, "--speedup must be > 0 and finite"),
    ("uav-sitl", "vehicle --sysid 300 --duration 1", 2, "--sysid must be in 1..255"),
    ("uav-sitl", "vehicle --count 10 --sysid 250 --duration 1", 2,
     "--sysid must be in 1..246 for 10 vehicle(s), got 250"),
    # the last vehicle's PORT+i was past 65535: an OverflowError traceback from bind()
    ("uav-sitl", "vehicle --port 65534 --count 4 --duration 1", 2,
     "--port must be in 1..65532 for 4 vehicle(s) (vehicle i uses PORT+i), got 65534"),
    ("uav-sitl", "vehicle --port 0 --count 4 --out 127.0.0.1:65535 --duration 1", 2,
     "--out port must be in 1..65532 for 4 vehicle(s) (vehicle i sends to PORT+i), got 65535"),
    ("uav-sitl", "vehicle --out 127.0.0.1:99999 --duration 1", 2,
     "port must be in 1..65535, got '127.0.0.1:99999'"),
    ("uav-sitl", "vehicle --wind nan 0 --duration 1", 2, "--wind: expected a speed >= 0"),
    ("uav-sitl", "vehicle --duration nan", 2, "--duration must be a number of seconds >= 0"),
    ("uav-sitl", "vehicle --pattern waypoints {binary}", 2, "not a text file"),
    ("uav-sitl", "vehicle --port 0 --duration 1 --ready-file /proc/nope/r.json", 1,
     "cannot write --ready-file"),
    ("uav-sitl", "vehicle --serial --count 2", 2, "--serial serves one vehicle"),
    ("uav-sitl", "camera --scene {binary} --pose 1,2,3 --out {folder}/f", 2, "not a text file"),
    ("uav-sitl", "camera --poses {binary} --out {folder}/f", 2, "can't decode"),
    ("uav-sitl", "camera --pose 1,2,3 --out /proc/nope", 1, "cannot write to /proc/nope"),
    # a mistyped scene name read as a missing file; now it names the scenes there are
    ("uav-sitl", "camera --scene dmeo --pose 1,2,3 --out {folder}/f", 2,
     "uav-sitl camera: no scene 'dmeo': not a bundled scene (demo) nor a file"),
    ("uav-sitl", "fleet --drones 1 --duration 1 --scene dmeo --out {folder}/run", 2,
     "uav-sitl fleet: no scene 'dmeo': not a bundled scene (demo) nor a file"),
    ("uav-sitl", "vehicle --scene dmeo --duration 1", 2,
     "uav-sitl vehicle: no scene 'dmeo': not a bundled scene (demo) nor a file"),
    # was "no token ([Errno 2] No such file or directory: '.../token'); pass --token"
    ("uav-ground-station", "shell --data-dir {folder} -c status", 2,
     "/folder/token (no such file): give the station's --data-dir or --config (as `run` got "
     "them), or --token"),
    ("uav-sitl", "fleet --drones 1 --duration 1 --scene {binary} --out {folder}/run", 2,
     "not a text file"),
    ("uav-sitl", "camera --pose 1,2,3 --hfov 200 --out {folder}/f", 2,
     "hfov_deg must be in [1, 179), got 200.0"),
    ("uav-sitl", "camera --pose 1,2,3 --hfov 0 --out {folder}/f", 2,
     "hfov_deg must be in [1, 179), got 0.0"),
    ("uav-sitl", "study drop-rate-vs-utility --quick --out /proc/nope", 1,
     "uav-sitl study drop-rate-vs-utility: /proc/nope: No such file or directory"),
    ("uav-sitl", "study bogus", 2, "unknown study 'bogus'; expected one of adaptive-vs-aimd"),
    ("uav-sitl", "camera --pose 1,2,3 --size 100000x100000 --out {folder}/f", 2,
     "width and height must be in 16..8192"),
    ("uav-sitl", "camera --pose nan,1,30 --out {folder}/f", 2, "expected finite numbers"),
    ("uav-sitl", "fleet --drones 1 --duration 1 --rate 0 --out {folder}/run", 2,
     "--rate must be a finite number > 0, got 0.0"),
    ("uav-sitl", "fleet --drones 1 --duration 1 --mcts-iterations 0 --out {folder}/run", 2,
     "--mcts-iterations must be in 1..1000000, got 0"),
    ("uav-sitl", "fleet --drones 1 --duration 1 --goodput -5 --out {folder}/run", 2,
     "--goodput must be a finite number of bytes/s >= 0, got -5.0"),
    ("uav-sitl", "fleet --drones 1 --duration 1 --speedup inf --out {folder}/run", 2,
     "--speedup must be a finite number > 0, got inf"),
    ("uav-sitl", "fleet --drones 1 --duration nan --out {folder}/run", 2,
     "--duration must be >= 0"),
    ("uav-sitl", "fleet --drones 1 --duration 1 --size 100000x100000 --out {folder}/run", 2,
     "--size: width and height must be in 16..8192"),
    # a wrong spec or port fails before the launcher starts anything (it failed later in the
    # ground station, after the run had been announced with a dashboard link)
    ("uav-sitl", "fleet --drones 1 --duration 1 --spec {binary} --out {folder}/run", 2,
     "--spec "),
    ("uav-sitl", "fleet --drones 1 --duration 1 --spec nosuch --out {folder}/run", 2,
     "nosuch.toml: no such spec file"),
    # ran the whole mission, then "[Errno 17] File exists", exit 2 and no summary printed
    ("uav-sitl", "fleet --drones 1 --duration 1 --summary-json {a_file}/s.json --out "
     "{folder}/run", 2, "/a_file is a file, not a folder"),
    ("uav-sitl", "fleet --drones 1 --duration 1 --summary-json {folder} --out {folder}/run",
     2, "is a folder; give a file name"),
    ("uav-sitl", "fleet --drones 1 --duration 1 --http-port 99999 --out {folder}/run", 2,
     "--http-port must be in 0..65535, got 99999"),
    ("uav-utility", "evaluate --spec {deep_toml} {deep_jsonl}", 2, "nested too deeply"),
    ("uav-utility", "evaluate --spec telemetry {deep_jsonl}", 2,
     "deep.jsonl:1: JSON nested too deeply"),
    ("uav-utility", "evaluate --spec telemetry {binary}", 2, "not a text file"),
    ("uav-utility", "evaluate --spec {binary} {deep_jsonl}", 2, "not a text file"),
    ("uav-utility", "evaluate --spec telemetry {folder}", 2, "cannot read (Is a directory)"),
    ("uav-utility", "plot 4.9 --out /proc/nope/x.png", 1, "cannot write /proc/nope/x.png"),
]


@pytest.mark.parametrize(("script", "argv", "code", "fragment"), CASES,
                         ids=[f"{c[0]} {c[1]}" for c in CASES])
def test_bad_input_is_one_line_and_nonzero(bad: dict[str, Path], script: str, argv: str,
                                           code: int, fragment: str) -> None:
    names = {k: str(v) for k, v in bad.items()}
    args = argv.format(**names).split()
    result = subprocess.run([_tool(script), *args], capture_output=True, text=True,
                            timeout=60, check=False)
    assert_one_line_error(result, code, fragment.format(**names) if "{" in fragment
                          else fragment)


def test_vehicle_on_a_busy_port_names_the_ports_and_the_flag() -> None:
    """Was "uav-sitl vehicle: cannot bind: [Errno 98] Address already in use": which port, and
    what to do, was left to guess (a vehicle still running from the README's `&`)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1] - 1  # the second of two vehicles finds it taken
        result = subprocess.run([_tool("uav-sitl"), "vehicle", "--port", str(port), "--count",
                                 "2", "--duration", "1"], capture_output=True, text=True,
                                timeout=60, check=False)
    assert_one_line_error(result, 1, f"uav-sitl vehicle: cannot bind UDP 127.0.0.1:{port}.."
                          f"{port + 1}: address already in use (another vehicle or program "
                          "listens there): stop it, or pick another --port")


def test_fleet_on_a_busy_dashboard_port_fails_before_announcing_the_run(
        bad: dict[str, Path]) -> None:
    """It printed the run's dashboard login link for the busy port, started the vehicles and
    companions, then quoted the ground station's failure (a newcomer's --http-port)."""
    with socket.socket() as squatter:
        squatter.bind(("127.0.0.1", 0))
        squatter.listen()
        port = squatter.getsockname()[1]
        result = subprocess.run([_tool("uav-sitl"), "fleet", "--drones", "1", "--duration", "1",
                                 "--http-port", str(port), "--out", str(bad["folder"] / "busy")],
                                capture_output=True, text=True, timeout=60, check=False)
    assert_one_line_error(result, 2, f"--http-port {port} is already in use on 127.0.0.1 "
                          "(another program listens there): stop it, or pick another")
    assert "login=" not in result.stdout
    assert not (bad["folder"] / "busy").exists()


def test_export_does_not_create_a_database(bad: dict[str, Path]) -> None:
    subprocess.run([_tool("uav-ground-station"), "export", "m1", "--data-dir",
                    str(bad["no_db"]), "--out", str(bad["folder"] / "y")],
                   capture_output=True, timeout=60, check=False)
    assert not bad["no_db"].exists()


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.mark.timeout(90)
def test_image_urls_out_of_range_are_404_not_500(tmp_path: Path) -> None:
    http_port = _free_port()
    write_test_keys(tmp_path / "gs" / "keys")
    proc = subprocess.Popen([_tool("uav-ground-station"), "run", "--data-dir",
                             str(tmp_path / "gs"), "--udp-port", "0", "--http-port",
                             str(http_port)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert "control token" in line, line + proc.stderr.read() if proc.stderr else line
        token = line.rsplit(": ", 1)[1].strip()
        base = f"http://127.0.0.1:{http_port}"
        auth = {"Authorization": f"Bearer {token}"}  # never in the URL
        deadline = time.monotonic() + 30
        while True:
            try:
                urllib.request.urlopen(urllib.request.Request(f"{base}/api/fleet", headers=auth),
                                       timeout=2)
                break
            except (urllib.error.URLError, ConnectionError):
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise
                time.sleep(0.2)
        for image_id in ("1" * 26, "9223372036854775808", "-1", "%D9%A3", "1_0", "007"):
            request = urllib.request.Request(f"{base}/api/images/{image_id}.jpg",
                                             headers=auth)
            with pytest.raises(urllib.error.HTTPError) as err:
                urllib.request.urlopen(request, timeout=5)
            assert err.value.code == 404, image_id
        assert proc.poll() is None
    finally:
        proc.terminate()
        try:
            _, err_text = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err_text = proc.communicate()
    assert "Traceback" not in err_text, err_text[-3000:]
