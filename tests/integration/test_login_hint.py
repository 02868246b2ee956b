"""The "another:" command `uav-ground-station run` prints next to its login link makes a link
for that very station. Walking the README as a newcomer: `run --http-port 18091` printed
`another: uav-ground-station token --url --data-dir gs-data`, which gave a link to port 8080
(the config's default), where nothing listened."""

from __future__ import annotations

import shlex
import subprocess
import urllib.error
import urllib.request
from pathlib import Path

from tests.station_process import STATION, running_station


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args: object, **kwargs: object) -> None:
        return None


def test_the_printed_token_command_logs_in_to_the_running_station(tmp_path: Path) -> None:
    with running_station(tmp_path) as station:  # --http-port 0: the OS picks the port
        assert "another: uav-ground-station token --url " in station.dashboard_line
        hint = station.dashboard_line.split("another: ", 1)[1].rstrip(")")
        words = shlex.split(hint)
        assert words[:3] == ["uav-ground-station", "token", "--url"]
        assert words[words.index("--http-port") + 1] == str(station.port)
        made = subprocess.run([str(STATION), *words[1:]], capture_output=True, text=True,
                              timeout=60, cwd=tmp_path)
        assert made.returncode == 0, made.stderr
        url = made.stdout.strip()
        assert url.startswith(f"http://127.0.0.1:{station.port}/?login="), url
        opener = urllib.request.build_opener(_NoRedirect)
        try:
            opener.open(url, timeout=10)
            raise AssertionError("the login link did not redirect")
        except urllib.error.HTTPError as reply:  # 303 to "/" with the session cookie
            assert reply.code == 303  # and the page key in the fragment, for the page only
            assert reply.headers["Location"].split("#key=")[0] == "/"
            assert "gs_session=" in reply.headers["Set-Cookie"]
