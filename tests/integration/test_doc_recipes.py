"""Every command README.md and docs/*.md tell a user to run is run here (issue 11).

A recipe is a line of a fenced ``sh`` block (``\\`` continuations joined, comments dropped).
Each one is either

* in :data:`RECIPES`, naming the test below that runs that very text (through bash, with the
  worktree's console scripts first on PATH, ports and durations shortened by explicit
  substitutions), or
* in a block marked ``<!-- recipe: needs ... -->`` on the line before its fence (hardware,
  root, software that is not a dependency): the reason is the marker's text.

A new command in the docs without either fails :func:`test_every_recipe_is_run_or_marked`;
a registered command that left the docs fails it too, so the registry cannot rot. Every
fence must name its language (``sh`` for recipes, ``text`` for output and diagrams), so a
recipe cannot hide in an unlabelled block.
"""

from __future__ import annotations

import csv
import json
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
RECIPE_LANGUAGES = {"sh", "bash", "shell", "console"}
MARKER = re.compile(r"^<!--\s*recipe:\s*(needs .+?)\s*-->$")


@dataclass(frozen=True)
class Recipe:
    doc: str
    line: int
    command: str
    needs: str | None


def _blocks(path: Path) -> Iterator[tuple[int, str, str | None, list[str]]]:
    """(line, language, marker, lines) of each fenced block."""
    lines = path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        if lines[i].startswith("```"):
            language = lines[i][3:].strip()
            prev = next((x.strip() for x in reversed(lines[:i]) if x.strip()), "")
            marker = MARKER.match(prev)
            start = i
            body = []
            i += 1
            while i < len(lines) and not lines[i].startswith("```"):
                body.append(lines[i])
                i += 1
            yield start + 1, language, marker.group(1) if marker else None, body
        i += 1


def extract_recipes() -> list[Recipe]:
    recipes = []
    for path in DOCS:
        for line, language, needs, body in _blocks(path):
            if language not in RECIPE_LANGUAGES:
                continue
            joined: list[str] = []
            for raw in body:
                if joined and joined[-1].endswith("\\"):
                    joined[-1] = joined[-1][:-1].rstrip() + " " + raw.strip()
                else:
                    joined.append(raw)
            for text in joined:
                command = re.sub(r"\s+#\s.*$", "", text).strip()
                if command and not command.startswith("#"):
                    recipes.append(Recipe(path.relative_to(ROOT).as_posix(), line, command,
                                          needs))
    return recipes


README_KEYED_CONFIG = (
    "sed -e 's,^# fleet_key_file = \"/etc/uav-companion/,fleet_key_file = \"keys/,' -e "
    "'s,^# command_public_key_file = \"/etc/uav-companion/,command_public_key_file = \"keys/,' "
    "examples/companion.toml > companion.toml")
"""README's copy of the example config that names the keys ``keygen --out keys`` made."""

# command as written in the docs -> the test of this module that runs it
RECIPES: dict[str, str] = {
    # README.md
    "make demo": "test_make_demo_recipe",
    "make test": "test_developer_recipes",
    "uav-utility evaluate --spec image_streaming drone1.jsonl gs.jsonl":
        "test_fleet_recipe_and_evaluate_agree",
    "uav-utility evaluate --spec my_mission.toml mission.jsonl --json":
        "test_fleet_recipe_and_evaluate_agree",
    "uav-utility plot 4.9 --out fig49.png": "test_utility_plot_recipe",
    "uav-utility plot all --out out/plots": "test_utility_plot_all_recipe",
    "uav-ground-station keygen --out keys": "test_readme_companion_recipe",
    README_KEYED_CONFIG: "test_readme_companion_recipe",
    "uav-sitl vehicle --port 14580 --out 127.0.0.1:14550 &": "test_readme_companion_recipe",
    "uav-companion check --config companion.toml": "test_readme_companion_recipe",
    # docs/companion.md
    "uav-sitl vehicle --serial --serial-link /tmp/ttyFC --baud 57600 &":
        "test_companion_serial_recipe",
    "uav-companion check --config serial.toml": "test_companion_serial_recipe",
    # docs/fleet.md
    "uav-sitl fleet --drones 2 --duration 60": "test_fleet_recipe_and_evaluate_agree",
    "uav-sitl fleet --drones 4 --scene my_scene.toml --duration 120 --summary-json out/s.json":
        "test_fleet_variant_recipes",
    "uav-sitl fleet --policy random --drop-probability 0.9 --duration 60":
        "test_fleet_variant_recipes",
    # docs/ground_station.md
    "uav-ground-station keygen": "test_ground_station_recipes",
    "uav-ground-station run": "test_ground_station_recipes",
    "uav-ground-station run --config gs.toml --mission survey-1": "test_ground_station_recipes",
    "uav-ground-station token": "test_ground_station_recipes",
    "uav-ground-station token --url": "test_ground_station_recipes",
    "uav-ground-station shell": "test_ground_station_recipes",
    'uav-ground-station shell -c "drones 4; start +5"': "test_ground_station_recipes",
    "uav-ground-station export survey-1 --out ./survey-1": "test_ground_station_recipes",
    "python -m ground_station.fake_drone 127.0.0.1:14600 --keys gs-data/keys":
        "test_ground_station_recipes",
    # docs/sitl.md
    "uav-sitl vehicle --port 14550": "test_sitl_quick_start_recipes",
    "uav-sitl vehicle --port 14550 --count 4 --flavour ardupilot --pattern survey --speedup 10 "
    "--autostart": "test_sitl_quick_start_recipes",
    "python -c \"from pymavlink import mavutil; m = mavutil.mavlink_connection("
    "'udpout:127.0.0.1:14550'); m.mav.heartbeat_send(6, 8, 0, 0, 0); print(m.wait_heartbeat())\"":
        "test_sitl_quick_start_recipes",
    "uav-sitl camera --scene demo --pose 20,30,30 --pose=-90,10,25,0,0,30 --out frames/ "
    "--texture": "test_sitl_quick_start_recipes",
    # docs/middleware.md and docs/adaptive.md
    "uav-sitl study drop-rate-vs-utility --out out/fig57 [--quick] [--scenario mostly-low]":
        "test_study_recipes",
    "uav-sitl study adaptive-vs-aimd --out out/adaptive [--real] [--time-scale 0.5]":
        "test_study_recipes",
    "uav-sitl study mcts-vs-baselines --out out/baselines [--quick] [--scenarios images]":
        "test_baselines_study_recipe",
    "python -m sitl.study.equal_bytes --out out/equal_bytes --quick --optimum "
    "--budgets 9.25,5.5,2.5": "test_equal_bytes_study_recipe",
    "python -m sitl.study.equal_bytes --out out/eb100 --t-end 100 --budgets 9.25,5.5,2.5":
        "test_equal_bytes_study_recipe",
    # docs/utility.md
    "uav-utility characteristics --spec image_streaming --type image --out out/fig72 "
    "out/fleet/*/drones/*/mission_log.jsonl": "test_fleet_recipe_and_evaluate_agree",
}
DEVELOPER = re.compile(r"^(sudo )?(\w+=\S+ )*\.venv/bin/python (-m pytest|benchmarks/)")
"""Developer commands (tests, benchmarks): checked by test_developer_recipes."""


def test_every_fence_names_its_language() -> None:
    unlabelled = [f"{p.relative_to(ROOT)}:{line}" for p in DOCS
                  for line, language, _, _ in _blocks(p) if not language]
    assert not unlabelled, ("fenced blocks without a language (sh for commands, text for "
                            f"output and diagrams): {unlabelled}")


def test_every_recipe_is_run_or_marked() -> None:
    recipes = extract_recipes()
    assert len(recipes) > 30  # the extraction works at all
    untested = [f"{r.doc}:{r.line}: {r.command}" for r in recipes
                if r.needs is None and r.command not in RECIPES
                and not DEVELOPER.match(r.command)]
    assert not untested, ("commands in the docs that no test runs: add them to RECIPES with a "
                          "test, or mark the block <!-- recipe: needs ... -->:\n"
                          + "\n".join(untested))
    in_docs = {r.command for r in recipes}
    stale = sorted(set(RECIPES) - in_docs)
    assert not stale, f"RECIPES entries no longer in the docs: {stale}"
    tests = {name for name in globals() if name.startswith("test_")}
    assert set(RECIPES.values()) <= tests
    marked = [r for r in recipes if r.needs is not None]
    assert marked and all(len(r.needs or "") > len("needs ") + 3 for r in marked)


def _recipe(command: str) -> str:
    """The docs' text of a registered command (fails if the docs changed it)."""
    assert command in RECIPES, command
    assert command in {r.command for r in extract_recipes()}, f"not in the docs: {command}"
    return command


def _sub(command: str, *pairs: tuple[str, str]) -> str:
    for old, new in pairs:
        assert old in command, (old, command)
        command = command.replace(old, new)
    return command


def _env() -> dict[str, str]:
    return {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}",
            "PYTHONUNBUFFERED": "1"}


def _bash(script: str, cwd: Path, *, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """Run doc text the way a user's shell would (``python`` is the venv's)."""
    result = subprocess.run(["bash", "-c", f"python() {{ {shlex.quote(sys.executable)} \"$@\"; }}"
                             f"\n{script}"], cwd=cwd, env=_env(), capture_output=True,
                            text=True, timeout=timeout, check=False)
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    return result


def _background(command: str, cwd: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(["bash", "-c", f"exec {command}"], cwd=cwd, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def _end(proc: subprocess.Popen[str]) -> tuple[str, str]:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
    return out, err


def _free_port(kind: int = socket.SOCK_DGRAM, *, span: int = 1) -> int:
    for _ in range(50):
        with socket.socket(socket.AF_INET, kind) as sock:
            sock.bind(("127.0.0.1", 0))
            port = int(sock.getsockname()[1])
        if port + span < 65000:
            return port
    raise AssertionError("no free port")


def _ready(proc: subprocess.Popen[str]) -> dict[str, object]:
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.startswith("READY "), line + (proc.stderr.read() if proc.stderr else "")
    return dict(json.loads(line.removeprefix("READY ")))


# ----------------------------------------------------------------------------- developers


def test_developer_recipes() -> None:
    """Test and benchmark commands name files that exist, selections that select and options
    the scripts define; running them is the suite's and ``make bench``'s job (``make test``
    is this suite itself)."""
    for recipe in extract_recipes():
        if not DEVELOPER.match(recipe.command):
            continue
        words = shlex.split(recipe.command)
        words = words[words.index(".venv/bin/python") + 1:]
        if words[:2] == ["-m", "pytest"]:
            paths = [w for w in words if w.startswith("tests")]
            assert paths, recipe
            files = [f for p in paths for f in ROOT.glob(p)]
            files = [x for f in files for x in ([f] if f.is_file() else f.rglob("test_*.py"))]
            assert files, f"{recipe.doc}:{recipe.line}: {paths} match no test file"
            text = "".join(f.read_text() for f in files)
            options = words[2:]
            if "-k" in options:  # the selection selects: pytest collects something with it
                selection = options[options.index("-k") + 1]
                collected = subprocess.run(
                    [sys.executable, "-m", "pytest", "--collect-only", "-q",
                     "-p", "no:cacheprovider", *paths, "-k", selection],
                    cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=120,
                    check=False)
                count = re.search(r"^(\d+)(?:/\d+)? tests? collected", collected.stdout, re.M)
                assert count is not None and int(count.group(1)) > 0, (
                    f"{recipe.doc}:{recipe.line}: -k {selection!r} selects nothing: "
                    + collected.stdout[-2000:] + collected.stderr[-2000:])
            if "-m" in options:
                assert f"mark.{options[options.index('-m') + 1]}" in text, recipe
        else:  # a benchmark: it exists and knows the options the docs give it
            script = ROOT / words[0]
            assert script.is_file(), recipe
            source = script.read_text()
            for option in (w.strip("[]") for w in words[1:] if w.strip("[]").startswith("--")):
                assert f'"{option}"' in source, f"{recipe.doc}:{recipe.line}: {option}"


# ----------------------------------------------------------------------------- README


@pytest.mark.timeout(120)
def test_readme_companion_recipe(tmp_path: Path) -> None:
    """Issue 11, symptom 3: the example config and the vehicle no longer fight for a port;
    the companion gets the keys ``keygen`` makes (there is no built-in one)."""
    shutil.copytree(ROOT / "examples", tmp_path / "examples")
    listen, vehicle_port = _free_port(), _free_port()
    example = tmp_path / "examples" / "companion.toml"
    example.write_text(_sub(example.read_text(), ('url = "udpin:127.0.0.1:14550"',
                                                  f'url = "udpin:127.0.0.1:{listen}"')))
    keygen = _bash(_recipe("uav-ground-station keygen --out keys"), tmp_path)
    assert keygen.returncode == 0, keygen.stdout + keygen.stderr
    assert sorted(p.name for p in (tmp_path / "keys").iterdir()) == [
        "command.key", "command.pub", "fleet.key"]
    copied = _bash(_recipe(README_KEYED_CONFIG), tmp_path)
    assert copied.returncode == 0, copied.stderr
    config = (tmp_path / "companion.toml").read_text()
    assert 'fleet_key_file = "keys/fleet.key"' in config
    assert 'command_public_key_file = "keys/command.pub"' in config
    vehicle = _background(_sub(_recipe("uav-sitl vehicle --port 14580 --out 127.0.0.1:14550 &"),
                               ("14580", str(vehicle_port)), ("14550", str(listen)),
                               (" &", "")), tmp_path)
    try:
        assert _ready(vehicle)["port"] == vehicle_port
        result = _bash(_recipe("uav-companion check --config companion.toml"), tmp_path,
                       timeout=90)
    finally:
        _end(vehicle)
    assert result.returncode == 0, result.stdout + result.stderr[-3000:]
    assert "keys: fleet key and the ground station's command key loaded" in result.stdout
    assert f"mavlink: udpin:127.0.0.1:{listen}: px4 autopilot" in result.stdout
    assert "camera: synthetic" in result.stdout
    assert result.stdout.rstrip().endswith("check: ok")


@pytest.mark.timeout(120)
def test_utility_plot_recipe(tmp_path: Path) -> None:
    one = _bash(_recipe("uav-utility plot 4.9 --out fig49.png"), tmp_path)
    assert one.returncode == 0, one.stderr
    assert (tmp_path / "fig49.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_utility_plot_all_recipe(tmp_path: Path) -> None:
    every = _bash(_recipe("uav-utility plot all --out out/plots"), tmp_path)
    assert every.returncode == 0, every.stderr
    assert len(list((tmp_path / "out" / "plots").glob("*.png"))) >= 9


# ----------------------------------------------------------------------------- companion


@pytest.mark.timeout(120)
def test_companion_serial_recipe(tmp_path: Path) -> None:
    link = tmp_path / "ttyFC"
    keygen = _bash("uav-ground-station keygen --out keys", tmp_path)  # README's step
    assert keygen.returncode == 0, keygen.stdout + keygen.stderr
    vehicle = _background(_sub(_recipe(
        "uav-sitl vehicle --serial --serial-link /tmp/ttyFC --baud 57600 &"),
        ("/tmp/ttyFC", str(link)), (" &", "")), tmp_path)
    try:
        ready = _ready(vehicle)
        assert str(ready["tty"]).startswith("/dev/pts/")
        (tmp_path / "serial.toml").write_text(
            f'[drone]\nid = "drone1"\n[mavlink]\nurl = "{link}"\nbaud = 57600\n'
            '[camera]\nenabled = false\n[ground_station]\nfleet_key_file = "keys/fleet.key"\n'
            'command_public_key_file = "keys/command.pub"\n')
        result = _bash(_recipe("uav-companion check --config serial.toml"), tmp_path)
    finally:
        _end(vehicle)
    assert result.returncode == 0, result.stdout + result.stderr[-3000:]
    assert f"mavlink: {link}: px4 autopilot" in result.stdout


# ----------------------------------------------------------------------------- sitl


@pytest.mark.timeout(120)
def test_sitl_quick_start_recipes(tmp_path: Path) -> None:
    one = _free_port()
    vehicle = _background(_sub(_recipe("uav-sitl vehicle --port 14550"),
                               ("14550", str(one))) + " --duration 30", tmp_path)
    try:
        assert _ready(vehicle)["port"] == one
        probe = _bash(_sub(_recipe(
            "python -c \"from pymavlink import mavutil; m = mavutil.mavlink_connection("
            "'udpout:127.0.0.1:14550'); m.mav.heartbeat_send(6, 8, 0, 0, 0); "
            "print(m.wait_heartbeat())\""), ("14550", str(one))), tmp_path, timeout=60)
    finally:
        _end(vehicle)
    assert probe.returncode == 0, probe.stderr
    assert probe.stdout.startswith("HEARTBEAT {type : 2, autopilot : 12")
    base = _free_port(span=4)
    four = _background(_sub(_recipe(
        "uav-sitl vehicle --port 14550 --count 4 --flavour ardupilot --pattern survey "
        "--speedup 10 --autostart"), ("14550", str(base))) + " --duration 30", tmp_path)
    try:
        readies = [_ready(four) for _ in range(4)]
    finally:
        _end(four)
    assert [r["port"] for r in readies] == [base + i for i in range(4)]
    assert all(r["flavour"] == "ardupilot" and int(str(r["mission_items"])) > 2
               for r in readies)
    camera = _bash(_recipe("uav-sitl camera --scene demo --pose 20,30,30 "
                           "--pose=-90,10,25,0,0,30 --out frames/ --texture"), tmp_path)
    assert camera.returncode == 0, camera.stderr
    frames = [json.loads(x) for x in camera.stdout.splitlines()]
    assert len(frames) == 2 and frames[0]["red_share"] > 0.0
    assert (tmp_path / "frames" / "ground_texture.png").is_file()


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_study_recipes(tmp_path: Path) -> None:
    fig57 = _bash(_sub(_recipe("uav-sitl study drop-rate-vs-utility --out out/fig57 [--quick] "
                               "[--scenario mostly-low]"),
                       ("[--quick] [--scenario mostly-low]", "--quick --scenario mostly-low")),
                  tmp_path, timeout=280)
    assert fig57.returncode == 0, fig57.stderr
    assert list((tmp_path / "out" / "fig57").glob("*.png"))
    adaptive = _bash(_sub(_recipe("uav-sitl study adaptive-vs-aimd --out out/adaptive [--real] "
                                  "[--time-scale 0.5]"),
                          ("[--real] [--time-scale 0.5]", "--time-scale 0.1")),
                     tmp_path, timeout=280)
    assert adaptive.returncode == 0, adaptive.stderr
    assert list((tmp_path / "out" / "adaptive").glob("*.png"))


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_baselines_study_recipe(tmp_path: Path) -> None:
    """docs/middleware.md's MCTS-vs-baselines study, quick, on the fastest scenario (the
    image-streaming one takes about 15 minutes even with ``--quick``)."""
    study = _bash(_sub(_recipe("uav-sitl study mcts-vs-baselines --out out/baselines "
                               "[--quick] [--scenarios images]"),
                       ("[--quick] [--scenarios images]", "--quick --scenarios mostly-low")),
                  tmp_path, timeout=280)
    assert study.returncode == 0, study.stdout[-3000:] + study.stderr[-3000:]
    out = tmp_path / "out" / "baselines"
    rows = (out / "baselines.csv").read_text().splitlines()
    assert len(rows) > 1 and all(r.startswith("mostly-low,") for r in rows[1:])
    table = (out / "baselines.md").read_text()
    assert "**mostly-low**" in table and "equal budget" in table and "equal bytes" in table


@pytest.mark.timeout(300)
def test_equal_bytes_study_recipe(tmp_path: Path) -> None:
    """docs/middleware.md's round 13 study (35 minutes as written), on the budget and scenario
    where the optimum's programme is fastest (about 10 s)."""
    study = _bash(_sub(_recipe("python -m sitl.study.equal_bytes --out out/equal_bytes --quick "
                               "--optimum --budgets 9.25,5.5,2.5"),
                       ("--budgets 9.25,5.5,2.5", "--budgets 2.5 --scenarios uniform")),
                  tmp_path, timeout=280)
    assert study.returncode == 0, study.stdout[-3000:] + study.stderr[-3000:]
    out = tmp_path / "out" / "equal_bytes"
    rows = (out / "equal_bytes.csv").read_text().splitlines()
    assert len(rows) == 4 and all(r.startswith("uniform,") for r in rows[1:])
    last = (out / "equal_bytes.md").read_text().splitlines()[-1]
    assert last.startswith("| uniform | 2.5 |") and "n/a" not in last
    assert (out / "equal_bytes.png").stat().st_size > 10_000
    # round 18's thesis-length run, on one seed of a 4 s uniform mission at one budget
    long = _bash(_sub(_recipe("python -m sitl.study.equal_bytes --out out/eb100 --t-end 100 "
                              "--budgets 9.25,5.5,2.5"),
                      ("--t-end 100", "--t-end 4 --seeds 1 --scenarios uniform"),
                      ("--budgets 9.25,5.5,2.5", "--budgets 9.25")), tmp_path, timeout=120)
    assert long.returncode == 0, long.stdout[-3000:] + long.stderr[-3000:]
    (row,) = csv.DictReader((tmp_path / "out" / "eb100" / "equal_bytes.csv").open())
    assert (row["scenario"], float(row["t_end"])) == ("uniform", 4.0)


# ----------------------------------------------------------------------------- ground station


def _wait_http(url: str, proc: subprocess.Popen[str], timeout_s: float = 30) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            urllib.request.urlopen(url, timeout=2)
            return
        except OSError:
            if proc.poll() is not None:
                raise AssertionError(f"exited: {_end(proc)[1][-3000:]}") from None
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


def _get(url: str, token: str) -> object:
    request = urllib.request.Request(url, headers={"Authorization": f"Bearer {token}"})
    with urllib.request.urlopen(request, timeout=5) as response:
        return json.loads(response.read())


def _check_login_link(made: subprocess.CompletedProcess[str], http: int) -> None:
    """``token --url``: a link that logs a browser in once (session cookie), then never."""
    assert made.returncode == 0, made.stderr
    link = made.stdout.strip()
    assert link.startswith(f"http://127.0.0.1:{http}/?login="), link
    stats = f"http://127.0.0.1:{http}/api/stats"
    browser = urllib.request.build_opener(urllib.request.HTTPCookieProcessor())
    with browser.open(link, timeout=5) as page:  # redirected to / with the cookie
        assert page.status == 200 and "login=" not in page.url, page.url
        # and the page key in the fragment, which the page keeps and sends with the cookie
        key = page.url.partition("#key=")[2]
    with browser.open(urllib.request.Request(stats, headers={"X-GS-Key": key}),
                      timeout=5) as response:
        assert response.status == 200
    again = urllib.request.build_opener(urllib.request.HTTPCookieProcessor())
    again.open(link, timeout=5).close()
    with pytest.raises(urllib.error.HTTPError) as refused:
        again.open(stats, timeout=5)
    assert refused.value.code == 401


@pytest.mark.timeout(180)
def test_ground_station_recipes(tmp_path: Path) -> None:
    data = tmp_path / "gs-data"
    udp, http = _free_port(), _free_port(socket.SOCK_STREAM)
    ports = f" --data-dir {data} --udp-port {udp} --http-port {http}"
    # the keys first (no built-in one): `run` finds them in DATA_DIR/keys
    keygen = _bash(_recipe("uav-ground-station keygen") + f" --data-dir {data}", tmp_path)
    assert keygen.returncode == 0, keygen.stdout + keygen.stderr
    assert sorted(p.name for p in (data / "keys").iterdir()) == [
        "command.key", "command.pub", "fleet.key"]
    # `run` with the defaults (ports moved), then the one with a config file and a mission
    station = _background(_recipe("uav-ground-station run") + ports, tmp_path)
    try:
        _wait_http(f"http://127.0.0.1:{http}/", station)
    finally:
        _end(station)
    token = _bash(_recipe("uav-ground-station token") + f" --data-dir {data}", tmp_path)
    assert token.returncode == 0 and len(token.stdout.strip()) >= 16, token.stderr
    key = token.stdout.strip()
    (tmp_path / "gs.toml").write_text(f'[ground_station]\ndata_dir = "gs-data"\n'
                                      f"udp_port = {udp}\nhttp_port = {http}\n")
    station = _background(_recipe("uav-ground-station run --config gs.toml --mission survey-1"),
                          tmp_path)
    drones = None
    try:
        _wait_http(f"http://127.0.0.1:{http}/", station)
        _check_login_link(_bash(_recipe("uav-ground-station token --url") + " --config gs.toml",
                                tmp_path), http)
        drones = _background(_sub(_recipe(
            "python -m ground_station.fake_drone 127.0.0.1:14600 --keys gs-data/keys"),
            ("python", shlex.quote(sys.executable)), ("14600", str(udp))), tmp_path)
        gs = f" --config gs.toml --url http://127.0.0.1:{http}"
        scripted = _bash(_recipe('uav-ground-station shell -c "drones 4; start +5"') + gs, tmp_path,
                         timeout=90)
        assert scripted.returncode == 0, scripted.stdout + scripted.stderr
        interactive = subprocess.run(["bash", "-c", _recipe("uav-ground-station shell") + gs],
                                     input="q\n", cwd=tmp_path, env=_env(),
                                     capture_output=True, text=True, timeout=60, check=False)
        assert interactive.returncode == 0, interactive.stdout + interactive.stderr
        assert "Traceback" not in interactive.stderr
        deadline = time.monotonic() + 60
        while True:
            images = _get(f"http://127.0.0.1:{http}/api/images?mission=survey-1&limit=500", key)
            if len(images["images"]) >= 4:  # type: ignore[index]
                break
            assert time.monotonic() < deadline, images
            time.sleep(0.5)
    finally:
        if drones is not None:
            _end(drones)
        _end(station)
    export = _bash(_recipe("uav-ground-station export survey-1 --out ./survey-1")
                   + " --config gs.toml", tmp_path)
    assert export.returncode == 0, export.stderr
    exported = list((tmp_path / "survey-1" / "images").glob("*.jpg"))
    assert len(exported) >= 4
    rows = (tmp_path / "survey-1" / "geotags.csv").read_text().splitlines()
    assert rows[0].startswith("image,latitude,longitude,altitude") and len(rows) >= 5


# ----------------------------------------------------------------------------- fleet


def _fleet(command: str, cwd: Path, *, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    result = _bash(command, cwd, timeout=timeout)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return result


@pytest.mark.timeout(300)
def test_fleet_recipe_and_evaluate_agree(tmp_path: Path) -> None:
    """docs/fleet.md's two-drone run, then README's ``uav-utility evaluate`` on its logs:
    the fleet summary and the evaluation agree (issue 11, symptom 5)."""
    run = tmp_path / "run"
    _fleet(_sub(_recipe("uav-sitl fleet --drones 2 --duration 60"), ("60", "6"))
           + f" --out {run} --summary-json {tmp_path / 'summary.json'} --http-port 0",
           tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    total = summary["utility"]["total"]
    assert total > 0
    shutil.copy(run / "drones" / "drone1" / "mission_log.jsonl", tmp_path / "drone1.jsonl")
    shutil.copy(run / "gs-data" / "missions" / "fleet" / "mission_log.jsonl",
                tmp_path / "gs.jsonl")
    table = _bash(_recipe("uav-utility evaluate --spec image_streaming drone1.jsonl gs.jsonl")
                  + " " + str(run / "drones" / "drone2" / "mission_log.jsonl"), tmp_path)
    assert table.returncode == 0, table.stderr
    assert f"total utility  {total:14.6f}" in table.stdout
    assert "interval: the only mission interval, from the receiver's (ground station's) log" \
        in table.stdout
    shutil.copy(ROOT / "utility_specs" / "missions" / "image_streaming.toml",
                tmp_path / "my_mission.toml")
    merged = "".join(p.read_text() for p in (tmp_path / "gs.jsonl", tmp_path / "drone1.jsonl"))
    merged += (run / "drones" / "drone2" / "mission_log.jsonl").read_text()
    (tmp_path / "mission.jsonl").write_text(merged)
    as_json = _bash(_recipe("uav-utility evaluate --spec my_mission.toml mission.jsonl --json"),
                    tmp_path)
    assert as_json.returncode == 0, as_json.stderr
    result = json.loads(as_json.stdout)
    assert result["total"] == pytest.approx(total, rel=1e-9)
    assert (result["t_start"], result["t_end"]) == (summary["t_start"], summary["t_end"])
    # docs/utility.md: the characteristics (thesis fig. 7.2) of the same run's frames
    chars = _bash(_sub(_recipe("uav-utility characteristics --spec image_streaming --type image "
                               "--out out/fig72 out/fleet/*/drones/*/mission_log.jsonl"),
                       ("out/fleet/*/drones", f"{run}/drones")), tmp_path)
    assert chars.returncode == 0, chars.stderr[-3000:]
    generated = sum(1 for d in ("drone1", "drone2") for line in
                    (run / "drones" / d / "mission_log.jsonl").read_text().splitlines()
                    if '"type":"image"' in line.replace(" ", ""))
    assert f"{generated} generated messages (image)" in chars.stdout
    assert (tmp_path / "out" / "fig72" / "characteristics.png").stat().st_size > 20_000


@pytest.mark.slow
@pytest.mark.timeout(400)
def test_fleet_variant_recipes(tmp_path: Path) -> None:
    shutil.copy(ROOT / "sitl" / "scenes" / "demo.toml", tmp_path / "my_scene.toml")
    _fleet(_sub(_recipe("uav-sitl fleet --drones 4 --scene my_scene.toml --duration 120 "
                        "--summary-json out/s.json"), ("--drones 4", "--drones 1"),
                ("120", "4")) + f" --out {tmp_path / 'a'} --http-port 0", tmp_path)
    assert json.loads((tmp_path / "out" / "s.json").read_text())["utility"]["total"] > 0
    random_run = _fleet(_sub(_recipe(
        "uav-sitl fleet --policy random --drop-probability 0.9 --duration 60"),
        ("60", "4")) + f" --drones 1 --out {tmp_path / 'b'} --http-port 0", tmp_path)
    assert "fleet summary (random" in random_run.stdout


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_make_demo_recipe() -> None:
    """``make demo`` as written, with one drone for 4 s (its own variables)."""
    assert _recipe("make demo") == "make demo"
    result = subprocess.run(["make", "demo", "DEMO_DRONES=1", "DEMO_DURATION=4"], cwd=ROOT,
                            env=_env(), capture_output=True, text=True, timeout=280,
                            check=False)
    run = re.search(r"^run folder: (.+)$", result.stdout, re.M)
    if run is not None and Path(run.group(1)).resolve().is_relative_to(ROOT / "out"):
        shutil.rmtree(run.group(1), ignore_errors=True)  # make demo writes into out/fleet/
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "fleet summary" in result.stdout and "total utility" in result.stdout
