"""Issue 32's viewer rows: no public share tunnel (button hidden, requests refused), and
'ebad view --host' with an address this machine cannot listen on or resolve stops at once
(one line, exit 2) instead of printing "Server stopped" and sleeping forever."""

from __future__ import annotations

import socket
import threading

import pytest

from ebad.cli import main
from ebad.runfolder import load_run

HANG_SECONDS = 30  # viser without the host check prints "Server stopped" and never returns


def _free_loopback_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_view_share_button_is_off_and_share_requests_open_no_tunnel(tiny_run, monkeypatch):
    viser = pytest.importorskip("viser", reason="the 'view' extra (viser) is not installed")
    import viser._messages as messages
    import viser._viser as viser_impl

    from ebad.cli.view import serve

    tunnels = []
    monkeypatch.setattr(viser_impl, "ViserTunnel", lambda *a, **k: tunnels.append(a) or pytest.fail("tunnel opened"))
    themes = []
    real_theme = viser.GuiApi.configure_theme

    def spy(self, *a, **k):
        themes.append(k)
        return real_theme(self, *a, **k)

    monkeypatch.setattr(viser.GuiApi, "configure_theme", spy)
    server, _ = serve(load_run(tiny_run.run), "127.0.0.1", _free_loopback_port())
    try:
        assert themes and themes[-1].get("show_share_button") is False  # the button is hidden
        assert server.request_share_url() is None
        # what a page (any client) sends when its Share button is pressed, button shown or not
        done = threading.Event()
        for handler in server._websock_server._incoming_handlers[messages.ShareUrlRequest]:
            handler(0, messages.ShareUrlRequest())
        server._thread_executor.submit(done.set)
        assert done.wait(10)
        server._thread_executor.submit(lambda: None).result(10)
        assert tunnels == []
    finally:
        server.stop()


@pytest.mark.parametrize("host", ["203.0.113.5", "nonexistent.invalid"])
def test_view_host_it_cannot_listen_on_is_one_line_and_exit_2(tiny_run, monkeypatch, capsys, host):
    pytest.importorskip("viser", reason="the 'view' extra (viser) is not installed")
    real = socket.getaddrinfo

    def no_dns(name, *a, **k):  # no lookup leaves the machine: .invalid never resolves
        if name == "nonexistent.invalid":
            raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")
        return real(name, *a, **k)

    monkeypatch.setattr(socket, "getaddrinfo", no_dns)
    result = []
    argv = ["view", str(tiny_run.run), "--host", host, "--port", str(_free_loopback_port())]
    worker = threading.Thread(target=lambda: result.append(main(argv)), daemon=True)  # a regression hangs here
    worker.start()
    worker.join(HANG_SECONDS)
    assert not worker.is_alive(), f"'ebad view --host {host}' still running after {HANG_SECONDS} s"
    rc = result[0]
    err = capsys.readouterr().err.strip()
    assert rc == 2 and f"--host {host}" in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("host", ["127.0.0.1", "0.0.0.0", "localhost", "::1"])
def test_view_host_check_accepts_this_machines_addresses(host):
    from ebad.cli.view import check_host

    if host == "::1" and not socket.has_ipv6:
        pytest.skip("no IPv6 on this machine")
    try:
        check_host(host)
    except Exception as exc:  # ::1 may be disabled in a container: then the error must name --host
        assert host == "::1" and f"--host {host}" in str(exc)
