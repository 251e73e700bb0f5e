"""Every STATUSTEXT goes out through daemon.outbound: a text longer than one message (50 bytes) as MAVLink 2 chunks
that a ground station joins back whole, and the rate limit passes a text whole or not at all.

The receiver here is written from the message definition (common.xml STATUSTEXT `id`, `chunk_seq`), not from the
daemon's code, with the two rules the ground stations apply: MAVProxy (mavproxy_link.py) keys a pending text by
(source, id) and takes it as complete when a chunk is shorter than 50 bytes (its NUL ends the text) or has id 0;
QGroundControl (StatusTextHandler) closes a pending text as incomplete, shown with " ... ", as soon as a
STATUSTEXT with another id arrives from the same component. The frames are packed and parsed by pymavlink."""

from __future__ import annotations

import random

from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.outbound import Identity, Outbound

TEXT_FIELD_BYTES = 50          # STATUSTEXT.text char[50]


class WireLink:
    """An endpoint that packs every message as a MAVLink 2 frame onto one byte stream."""

    def __init__(self):
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=200)
        self.stream = bytearray()

    def send(self, msg):
        self.stream += msg.pack(self.mav)
        return True

    def send_together(self, msgs):
        return all([self.send(m) for m in msgs])


class GroundStation:
    """Joins STATUSTEXT chunks as MAVProxy and QGroundControl do; `texts` whole, `incomplete` cut ones."""

    def __init__(self):
        self.texts: list[str] = []
        self.incomplete: list[str] = []
        self._pending: dict[int, dict[int, str]] = {}       # id -> {chunk_seq: text}
        self._last_seq: dict[int, int] = {}                 # id -> chunk_seq of the chunk that ended it

    def receive(self, stream: bytes) -> None:
        for m in mavlink.MAVLink(None).parse_buffer(bytes(stream)) or []:
            if m.get_type() == "STATUSTEXT":
                self._chunk(m.id, m.chunk_seq, m.text)

    def _chunk(self, text_id: int, seq: int, text: str) -> None:
        for other in [k for k in self._pending if k != text_id]:       # QGroundControl: another id closes it
            self.incomplete.append(self._joined(other))
        if text_id == 0:
            self.texts.append(text)
            return
        self._pending.setdefault(text_id, {})[seq] = text
        if len(text) < TEXT_FIELD_BYTES:                               # its NUL ends the text
            self._last_seq[text_id] = seq
        last = self._last_seq.get(text_id)
        if last is not None and sorted(self._pending[text_id]) == list(range(last + 1)):
            self.texts.append(self._joined(text_id))

    def _joined(self, text_id: int) -> str:
        chunks = self._pending.pop(text_id)
        self._last_seq.pop(text_id, None)
        return "".join(chunks[k] for k in sorted(chunks))


def _outbound(clock):
    counters = ServiceCounters()
    outbound = Outbound(Identity(1, 200, mavlink.MAV_TYPE_ONBOARD_CONTROLLER), counters, clock=clock)
    link = WireLink()
    outbound.endpoints.append(link)
    return outbound, link, counters


LONG = ("ahrsd: heading unknown: magnetometer disagrees with GNSS by 36°: calibration wrong or iron changed; "
        "no heading sent")
LONG_ASCII = LONG.replace("°", " deg")
EXACTLY_TWO = "ahrsd: " + "x" * (2 * TEXT_FIELD_BYTES - len("ahrsd: "))        # ends on a chunk boundary


def test_long_texts_arrive_whole_through_a_pymavlink_parser():
    outbound, link, _ = _outbound(lambda: 0.0)
    sent = ["ahrsd: short one", LONG, EXACTLY_TWO, LONG, "ahrsd: BOOT: waiting for the sensor"]
    for text in sent:
        outbound.statustext(mavlink.MAV_SEVERITY_WARNING, text)
    gcs = GroundStation()
    gcs.receive(link.stream)
    assert len(LONG_ASCII) > 2 * TEXT_FIELD_BYTES and len(EXACTLY_TWO) == 2 * TEXT_FIELD_BYTES
    assert gcs.texts == ["ahrsd: short one", LONG_ASCII, EXACTLY_TWO, LONG_ASCII,
                         "ahrsd: BOOT: waiting for the sensor"]
    assert gcs.incomplete == [] and gcs._pending == {}
    # two chunked texts in a row carry different ids: a receiver that lost the last chunk of one (MAVProxy keys
    # pending texts by id) must not join the next one onto it
    frames = mavlink.MAVLink(None).parse_buffer(bytes(link.stream))
    ids = [m.id for m in frames if m.chunk_seq == 0 and m.id != 0]
    assert len(ids) == 3 and len(set(ids)) == 3


def test_the_rate_limit_never_sends_part_of_a_text():
    """A flood at one instant: the burst of whole texts, the rest counted, nothing cut."""
    t = [0.0]
    outbound, link, counters = _outbound(lambda: t[0])
    for _ in range(40):
        outbound.statustext(mavlink.MAV_SEVERITY_WARNING, LONG)
    gcs = GroundStation()
    gcs.receive(link.stream)
    assert gcs.texts == [LONG_ASCII] * 10 and gcs.incomplete == [] and gcs._pending == {}   # the burst: 10 texts
    assert counters.statustext_suppressed == 30
    assert list(outbound.sent_texts) == [(mavlink.MAV_SEVERITY_WARNING, LONG)] * 10        # what went, as written


def test_a_flood_of_short_texts_does_not_starve_the_long_ones():
    """Sustained: every 0.1 s a peer's refusal (short) and one of the daemon's long texts, in a random order, twice
    the 5 texts/s the limit passes. One token per text: the long texts get about half of what passes, whole. (A
    charge of one token per chunk, all or none, would leave them almost nothing: the short ones take every token
    before three have gathered.)"""
    t = [0.0]
    outbound, link, counters = _outbound(lambda: t[0])
    rng = random.Random(1)
    for step in range(200):                       # 20 s
        t[0] = 0.1 * step
        texts = [(mavlink.MAV_SEVERITY_WARNING, "ahrsd: unknown parameter X"), (mavlink.MAV_SEVERITY_INFO, LONG)]
        rng.shuffle(texts)
        for severity, text in texts:
            outbound.statustext(severity, text)
    gcs = GroundStation()
    gcs.receive(link.stream)
    assert gcs.incomplete == [] and gcs._pending == {}
    assert 10 + 5 * 19 <= len(gcs.texts) <= 10 + 5 * 20       # the burst, then 5 texts/s
    assert gcs.texts.count(LONG_ASCII) >= 0.35 * len(gcs.texts)
    assert counters.statustext_suppressed == 400 - len(gcs.texts)


def test_critical_texts_pass_the_limit_whole():
    outbound, link, counters = _outbound(lambda: 0.0)
    for _ in range(20):
        outbound.statustext(mavlink.MAV_SEVERITY_INFO, "ahrsd: something")
    outbound.statustext(mavlink.MAV_SEVERITY_CRITICAL, LONG)
    gcs = GroundStation()
    gcs.receive(link.stream)
    assert gcs.texts[-1] == LONG_ASCII and len(gcs.texts) == 11 and counters.statustext_suppressed == 10


def test_the_service_runs_the_statustext_rate_limit_and_its_boot_time_on_the_clock_it_is_given(tmp_path):
    """Service hands its one clock to Outbound (and keeps its boot time on it): on a clock that only the test
    moves, texts are refused once the burst is spent and exactly one more goes out after a step of 1.25 tokens'
    time (5 texts/s), however long the machine took to get there."""
    from service_rig import gcs_socket, start_service, stop_service

    now_s = [100.0]
    gcs = gcs_socket()
    svc, loop = start_service(gcs, tmp_path, clock=lambda: now_s[0])
    out = []
    parser = mavlink.MAVLink(None)
    svc.endpoints[0].traffic_log = lambda frame: out.extend(
        m.text for m in parser.parse_buffer(frame) or () if m.get_type() == "STATUSTEXT")
    try:
        assert svc.time_boot_ms() == 0
        for i in range(20):                                  # the burst (10) spent, start-up texts included
            svc.statustext(mavlink.MAV_SEVERITY_INFO, f"ahrsd: text {i}")
        suppressed = svc.counters.statustext_suppressed
        assert 0 < suppressed and "ahrsd: text 19" not in out
        now_s[0] += 0.25
        svc.statustext(mavlink.MAV_SEVERITY_INFO, "ahrsd: after the step")
        svc.statustext(mavlink.MAV_SEVERITY_INFO, "ahrsd: refused again")
        assert out[-1] == "ahrsd: after the step"
        assert svc.counters.statustext_suppressed == suppressed + 1
        assert svc.time_boot_ms() == 250
    finally:
        stop_service(svc, loop)
        gcs.close()
