"""The shipped reverse proxy (``docker/nginx.conf``) logs no kit token.

A phone kit opens its stream as ``/ws/ingest?token=<kit token>`` (a browser cannot set a
WebSocket's header), and the server's own log masks it; but ``docker/nginx.conf`` named no
access log, so nginx wrote its default one (the ``combined`` format: the request line, query
string and all) — every phone kit's token in the proxy's log, for whoever reads it to send
data into that patient's record. Debian's nginx runs the shipped file (its upstreams and
paths pointed at this test's) in front of a real server."""

from __future__ import annotations

import json
import re
import subprocess
import time
from pathlib import Path

import httpx
import pytest
from server_support import ServerProcess, free_port
from test_security_limits import NGINX
from websockets.sync.client import connect

SHIPPED = Path(__file__).resolve().parents[1] / "docker" / "nginx.conf"


def runnable(conf: str, prefix: Path, port: int, upstream: int) -> str:
    """The shipped configuration on this machine: its upstreams the test's server, its
    port free, its files in ``prefix``. An ``access_log`` it names writes to
    ``prefix/access.log`` in its format; without one, nginx's default is put there as
    nginx would write it (``combined``)."""
    conf = re.sub(r"server app-\d+:8000[^;]*;", f"server 127.0.0.1:{upstream};", conf)
    conf = conf.replace("listen 8080;", f"listen 127.0.0.1:{port};")
    if "access_log" in conf:
        conf = re.sub(r"access_log\s+\S+", f"access_log {prefix}/access.log", conf)
    else:
        conf = conf.replace("http {", f"http {{\n    access_log {prefix}/access.log;", 1)
    conf = conf.replace("http {", f"""http {{
    client_body_temp_path {prefix}/body;
    proxy_temp_path {prefix}/proxy;
    fastcgi_temp_path {prefix}/fastcgi;
    uwsgi_temp_path {prefix}/uwsgi;
    scgi_temp_path {prefix}/scgi;""", 1)
    return (f"daemon off;\nworker_processes 1;\npid {prefix}/nginx.pid;\n"
            f"error_log {prefix}/error.log;\n{conf}")


def test_the_shipped_proxy_logs_no_kit_token(tmp_path):
    if NGINX is None:
        pytest.skip("needs Debian's nginx: apt-get install -y nginx (.ci/install installs it)")
    server = ServerProcess(tmp_path / "server")
    server.create_user("alice")
    server.start()
    prefix = tmp_path / "nginx"
    prefix.mkdir()
    port = free_port()
    conf = prefix / "nginx.conf"
    conf.write_text(runnable(SHIPPED.read_text(), prefix, port, server.port))
    nginx = subprocess.Popen([NGINX, "-p", str(prefix), "-c", str(conf)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        url = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 30
        while True:
            try:
                httpx.get(url + "/healthz", timeout=2)
                break
            except httpx.HTTPError:
                assert nginx.poll() is None, (prefix / "error.log").read_text()
                assert time.monotonic() < deadline, "nginx did not start"
                time.sleep(0.1)
        api = server.client("alice")
        kit = api.device(api.patient("Ada")["id"])
        # the phone kit's way: the token in the query string
        with connect(f"ws://127.0.0.1:{port}/ws/ingest?token={kit['token']}",
                     proxy=None) as ws:
            ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "phone",
                                "side": "right", "sensors": ["forearm"], "rate_hz": 50,
                                "nine_axis": False, "resume": None}))
            assert json.loads(ws.recv(30))["type"] == "ready"
            ws.send(json.dumps({"type": "bye"}))
        nginx.terminate()
        nginx.wait(10)  # the log is written out
        logged = (prefix / "access.log").read_text()
        print("nginx's access log:\n" + logged)
        assert "/ws/ingest" in logged  # the request is logged
        assert kit["token"] not in logged, "the kit's token is in the proxy's log"
    finally:
        if nginx.poll() is None:
            nginx.terminate()
            nginx.wait(10)
        server.stop()
