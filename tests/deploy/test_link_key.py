"""The keyed robot link: the key file, the challenge-response of :mod:`jaxenvs.deploy.auth`
at both ends (the simulated robot, :class:`TcpRobot`, the firmware example), and the
refusal to listen beyond the loopback without a key."""

from __future__ import annotations

import importlib.util
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from jaxenvs import cli
from jaxenvs.deploy import auth, simrobot, wire
from jaxenvs.deploy.link import TcpRobot

ROOT = Path(__file__).resolve().parents[2]
KEY = b"0123456789abcdef0123456789abcdef"


def _key_file(path: Path, key: bytes = KEY, mode: int = 0o600) -> Path:
    path.write_bytes(key + b"\n")
    path.chmod(mode)
    return path


# ------------------------------------------------------------------------- the key itself
def test_key_file_is_checked(tmp_path):
    good = _key_file(tmp_path / "good.key", mode=0o640)
    assert auth.read_key(good) == KEY  # the trailing newline stripped; group may read
    shared = _key_file(tmp_path / "shared.key", mode=0o644)
    with pytest.raises(ValueError, match=r"readable or writable by every user \(mode 0644\)"):
        auth.read_key(shared)
    with pytest.raises(ValueError, match="shorter than 16 bytes; make one with"):
        auth.read_key(_key_file(tmp_path / "short.key", b"secret"))
    with pytest.raises(ValueError, match="cannot read the key file"):
        auth.read_key(tmp_path / "missing.key")
    with pytest.raises(ValueError, match="not a regular file"):
        auth.read_key(tmp_path)


def test_proof_binds_key_role_and_both_nonces():
    a, b = auth.nonce(), auth.nonce()
    assert a != b and auth.valid_nonce(a) and len(a) == 2 * auth.NONCE_BYTES
    mac = auth.proof(KEY, "loop", a, b)
    assert auth.verify(KEY, "loop", a, b, mac)
    others = [
        auth.proof(KEY[:-1] + b"X", "loop", a, b),
        auth.proof(KEY, "robot", a, b),
        auth.proof(KEY, "loop", b, a),
    ]
    assert mac not in others
    assert not auth.verify(KEY, "loop", a, b, mac.upper())
    assert not auth.verify(KEY, "loop", a, b, None) and not auth.verify(KEY, "loop", a, b, 7)
    assert not auth.valid_nonce("xyz" * 20) and not auth.valid_nonce(12)


def test_loopback_addresses():
    for host in ("127.0.0.1", "::1", "localhost", "127.0.0.2"):
        assert auth.is_loopback(host), host
    for host in ("0.0.0.0", "::", "192.168.1.5", "8.8.8.8"):
        assert not auth.is_loopback(host), host
    simrobot.check_listen("tcp://127.0.0.1:0", None)
    simrobot.check_listen("tcp://0.0.0.0:0", KEY)
    simrobot.check_listen("tcp://0.0.0.0:0", None, insecure=True)
    with pytest.raises(ValueError, match="give --key-file FILE"):
        simrobot.check_listen("tcp://0.0.0.0:0", None)


def _jaxenvs(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}
    return subprocess.run(
        [sys.executable, "-m", "jaxenvs", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )


def test_robot_command_refuses_every_interface_without_a_key(tmp_path):
    """``jaxenvs robot --listen tcp://0.0.0.0:P`` without a key is one line naming
    --key-file, before the world is built (it used to serve every address)."""
    done = _jaxenvs("robot", "CartPole-v0", "--listen", "tcp://0.0.0.0:0")
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith("jaxenvs robot: error: listening on 0.0.0.0 without a key")
    assert "--key-file" in done.stderr and len(done.stderr.strip().splitlines()) == 1


def test_robot_command_refuses_a_key_every_user_can_read(tmp_path, capsys):
    key = _key_file(tmp_path / "robot.key", mode=0o604)
    argv = ["robot", "CartPole-v0", "--listen", "tcp://0.0.0.0:0", "--key-file", str(key)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("jaxenvs robot: error: the key file") and f"chmod 600 {key}" in err


# ----------------------------------------------------------------- the simulated robot's side
@pytest.fixture(scope="module")
def world():
    return simrobot.build_world("CartPole-v0", seed=0)


def _read(sock: socket.socket, reader: wire.FrameReader, n: int = 1) -> list[dict]:
    got: list[dict] = []
    while len(got) < n:
        data = sock.recv(1 << 16)
        if not data:
            break
        got += reader.feed(data)
    return got


def _episode_on_pair(world, client, key=KEY, opts=None):
    """Run one keyed episode on a socket pair (the robot's end closed when it returns) with
    ``client(sock)`` on the other end."""
    ours, theirs = socket.socketpair()
    result: dict = {}
    opts = opts or simrobot.LinkOptions(seconds=5)

    def robot():
        with ours:
            result["ep"] = simrobot.run_episode(world, ours, world.starts[0], opts, key)

    thread = threading.Thread(target=robot)
    thread.start()
    try:
        client(theirs)
    finally:
        thread.join(10)
        theirs.close()
    assert not thread.is_alive()
    return result["ep"]


def test_sim_robot_serves_a_client_that_proves_the_key(world):
    def client(sock):
        reader = wire.FrameReader()
        (challenge,) = _read(sock, reader)
        assert challenge["type"] == "challenge" and auth.valid_nonce(challenge["nonce"])
        ours = auth.nonce()
        mac = auth.proof(KEY, "loop", challenge["nonce"], ours)
        sock.sendall(wire.encode({"type": "auth", "nonce": ours, "mac": mac}))
        hello = _read(sock, reader)[0]
        assert hello["type"] == "hello"
        assert auth.verify(KEY, "robot", ours, challenge["nonce"], hello["mac"])
        sock.sendall(wire.encode(wire.command(0, np.array([0.5]))))
        frames = [m for m in _read(sock, reader, 12) if m["type"] == "sensors"]
        assert frames[-1]["acked"] == 0
        sock.sendall(wire.encode({"type": "bye", "reason": "done"}))

    ep = _episode_on_pair(world, client)
    assert not ep.refused and ep.closed == "bye" and ep.acked == 0


@pytest.mark.parametrize("answer", ["wrong_key", "a_command", "silence"])
def test_sim_robot_gives_nothing_to_a_client_without_the_key(world, answer, monkeypatch):
    """A wrong proof, a command instead of the answer, or no answer: a bye, no hello, no
    sensor frame, and no command applied."""
    monkeypatch.setattr(auth, "AUTH_TIMEOUT", 0.3)

    def client(sock):
        reader = wire.FrameReader()
        (challenge,) = _read(sock, reader)
        command = wire.encode(wire.command(0, np.array([1.0])))
        if answer == "wrong_key":
            ours = auth.nonce()
            mac = auth.proof(b"not-the-robots-key-at-all", "loop", challenge["nonce"], ours)
            sock.sendall(wire.encode({"type": "auth", "nonce": ours, "mac": mac}) + command)
        elif answer == "a_command":
            sock.sendall(command)
        rest = _read(sock, reader, 5)  # until the robot closes
        assert [m["type"] for m in rest] == ["bye"], rest

    ep = _episode_on_pair(world, client)
    assert ep.refused and ep.frames == 0 and ep.acked == -1
    assert ep.data.ctrl[0] == 0.0
    want = "no answer to the challenge" if answer == "silence" else auth.REFUSED
    assert ep.closed.startswith(want)


def test_a_client_gone_before_the_challenge_is_refused(world):
    """A client that resets the link before the challenge goes out (sending it fails)
    proved nothing: refused, so ``jaxenvs robot --once`` keeps waiting for its owner
    (it used to count the stranger as its one client and exit)."""
    ours, theirs = socket.socketpair()
    theirs.close()
    with ours:
        ep = simrobot.run_episode(world, ours, world.starts[0], simrobot.LinkOptions(), KEY)
    assert ep.refused and ep.closed == "link lost" and ep.frames == 0


# ------------------------------------------------------------------------- the loop's side
def _serve_once(handler) -> tuple[str, threading.Thread, socket.socket]:
    server = socket.create_server(("127.0.0.1", 0))

    def run():
        conn, _ = server.accept()
        with conn:
            handler(conn)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return f"tcp://127.0.0.1:{server.getsockname()[1]}", thread, server


def _sim(world, key):
    return lambda conn: simrobot.run_episode(
        world, conn, world.starts[0], simrobot.LinkOptions(seconds=5), key
    )


def test_tcp_robot_proves_the_key_and_is_driven(world):
    address, thread, server = _serve_once(_sim(world, KEY))
    robot = TcpRobot(address, key=KEY)
    try:
        assert robot.connect() == world.spec
        end = time.monotonic() + 5
        while robot.latest() is None and time.monotonic() < end:
            time.sleep(0.005)
        assert robot.latest() is not None
    finally:
        robot.close()
        thread.join(10)
        server.close()


@pytest.mark.parametrize(
    ("robot_key", "loop_key", "error"),
    [
        (KEY, b"another-key-of-enough-bytes", "refused the key"),
        (KEY, None, "asks for a key: give --key-file"),
        (None, KEY, "asks for no key"),
    ],
    ids=["wrong_key", "no_key", "unkeyed_robot"],
)
def test_tcp_robot_key_mismatch_is_one_line(world, robot_key, loop_key, error):
    address, thread, server = _serve_once(_sim(world, robot_key))
    robot = TcpRobot(address, key=loop_key)
    try:
        with pytest.raises(ValueError, match=error) as err:
            robot.connect()
        assert "\n" not in str(err.value)
    finally:
        robot.close()
        thread.join(10)
        server.close()


def test_tcp_robot_refuses_a_robot_that_does_not_prove_the_key(world):
    """A robot that challenges but cannot answer (an impostor without the key) is never
    driven: its hello's mac does not verify."""

    def impostor(conn):
        reader = wire.FrameReader()
        conn.sendall(wire.encode({"type": "challenge", "version": 1, "nonce": auth.nonce()}))
        _read(conn, reader)  # the loop's answer, which it cannot check
        hello = {"type": "hello", "version": 1, "mac": "0" * 64, **world.spec.to_json()}
        conn.sendall(wire.encode(hello))
        _read(conn, reader)

    address, thread, server = _serve_once(impostor)
    robot = TcpRobot(address, key=KEY)
    try:
        with pytest.raises(ValueError, match="did not prove it holds the key"):
            robot.connect()
    finally:
        robot.close()
        thread.join(10)
        server.close()


# --------------------------------------------------------------------- the firmware example
def _firmware():
    spec = importlib.util.spec_from_file_location(
        "robot_firmware", ROOT / "examples/robot_firmware.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_firmware_example_speaks_the_keyed_link(world):
    """The documented firmware example proves the key to :class:`TcpRobot` and applies only
    the valid commands; with the wrong key it sends nothing and applies nothing."""
    fw = _firmware()
    stub = fw.Robot(world.spec.to_json())
    counts: dict = {}
    address, thread, server = _serve_once(
        lambda conn: counts.update(fw.serve_client(conn, stub, KEY))
    )
    robot = TcpRobot(address, key=KEY)
    try:
        assert robot.connect() == world.spec
        robot.send(0, np.array([0.5]))
        nan = b'{"type":"command","seq":1,"action":[NaN]}'
        robot.sock.sendall(len(nan).to_bytes(4, "big") + nan)
        robot._send({"type": "command", "seq": 2, "action": [0.1, 0.2]})
        robot._send({"type": "command", "seq": 0, "action": [0.3]})
        end = time.monotonic() + 5
        while (robot.latest() is None or robot.latest().acked < 0) and time.monotonic() < end:
            time.sleep(0.005)
        assert robot.latest().acked == 0
    finally:
        robot.close()
        thread.join(10)
        server.close()
    assert stub.applied == [[0.5]] and stub.held
    assert counts == {"non_finite": 1, "wrong_size": 1, "stale": 1}

    stub = fw.Robot(world.spec.to_json())
    address, thread, server = _serve_once(lambda conn: fw.serve_client(conn, stub, KEY))
    robot = TcpRobot(address, key=b"another-key-of-enough-bytes")
    try:
        with pytest.raises(ValueError, match="refused the key"):
            robot.connect()
    finally:
        robot.close()
        thread.join(10)
        server.close()
    assert stub.applied == []


# ------------------------------------------------------------------------------ end to end
@pytest.mark.full
def test_keyed_robot_serves_on_after_a_client_without_the_key(tmp_path):
    """``jaxenvs robot --key-file`` on every interface: a client with the wrong key is
    refused and the robot serves on; ``jaxenvs deploy --key-file`` with the right one
    drives it."""
    key = _key_file(tmp_path / "robot.key")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}
    robot = subprocess.Popen(
        [sys.executable, "-m", "jaxenvs", "robot", "CartPole-v0", "--listen", "tcp://0.0.0.0:0"]
        + ["--once", "--key-file", str(key)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert robot.stdout is not None
        port = robot.stdout.readline().strip().rsplit(":", 1)[1]
        intruder = TcpRobot(f"tcp://127.0.0.1:{port}", key=b"another-key-of-enough-bytes")
        with pytest.raises(ValueError, match="refused the key"):
            intruder.connect()
        intruder.close()
        from pd_policy import pd_policy

        policy = pd_policy(tmp_path / "pd.npz")
        done = _jaxenvs(
            "deploy", str(policy), "--env", "CartPole-v0", "--robot", f"tcp://127.0.0.1:{port}",
            "--seconds", "1", "--key-file", str(key),
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        assert done.stdout.strip().splitlines()[-1].startswith("CartPole-v0: 50 steps")
        _, err = robot.communicate(timeout=30)
        assert robot.returncode == 0 and "refused 127.0.0.1: authentication failed" in err
    finally:
        robot.kill()
        robot.communicate()
