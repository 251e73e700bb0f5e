"""`ahrsd run --replay …` by its main in this process, its MAVLink drained from a UDP socket by a thread: for a
test whose check is what the daemon sends of a recording, not its process."""

from __future__ import annotations

from ahrsd.daemon.mavlink_io import mavlink


def replay_inproc(tmp_path, *args: str) -> dict:
    """`ahrsd run ARGS` of a replay (which ends by itself, status 0) by its main in this process (no interpreter,
    imports and kernel loads of a daemon process: what these tests check is the daemon's output, not its process),
    its MAVLink sent to a UDP socket that a thread drains meanwhile; then every message of our component by type,
    in arrival order."""
    import logging
    import socket
    import threading

    from ahrsd.cli.main import main
    from support.ahrsd_process import OUR_COMP
    from support.udp_drops import widen_receive_buffer

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    widen_receive_buffer(sock)
    sock.settimeout(0.1)
    datagrams: list[bytes] = []
    replayed = threading.Event()

    def drain():       # only the datagrams here: parsed after the run, so the daemon keeps the interpreter
        while True:
            try:
                datagrams.append(sock.recv(65535))
            except socket.timeout:
                if replayed.is_set():
                    return

    ours = logging.getLogger("ahrsd")
    level = ours.level                                  # `ahrsd run` lets the daemon's INFO through: restored
    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        rc = main(["run", *args, "--mavlink", f"udpout:127.0.0.1:{sock.getsockname()[1]}", "--state-dir",
                   str(tmp_path / "state"), "--status-line", "off"])
    finally:
        replayed.set()
        reader.join(30)
        sock.close()
        ours.setLevel(level)
    assert rc == 0
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    got: dict = {}
    for data in datagrams:
        for m in parser.parse_buffer(data) or ():
            if m.get_type() != "BAD_DATA" and m.get_srcComponent() == OUR_COMP:
                got.setdefault(m.get_type(), []).append((None, m))
    return got
