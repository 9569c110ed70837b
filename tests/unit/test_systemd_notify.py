"""The readiness datagram systemd reads from $NOTIFY_SOCKET (sd_notify(3))."""

from __future__ import annotations

import socket

from controller.shell.systemd_notify import notify


def test_notify_sends_the_state_to_the_socket_named_in_the_environment(tmp_path, monkeypatch):
    path = tmp_path / "notify"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind(str(path))
        monkeypatch.setenv("NOTIFY_SOCKET", str(path))
        assert notify("READY=1")
        assert server.recv(64) == b"READY=1"


def test_notify_uses_the_abstract_namespace_for_an_at_sign(monkeypatch):
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind(f"\0cheope-notify-test-{id(server)}")
        monkeypatch.setenv("NOTIFY_SOCKET", "@" + server.getsockname()[1:].decode())
        assert notify("STOPPING=1")
        assert server.recv(64) == b"STOPPING=1"


def test_without_a_service_manager_nothing_is_sent(monkeypatch, tmp_path):
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    assert not notify("READY=1")
    monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "gone"))
    assert not notify("READY=1")  # a manager that went away is not an error of the run
