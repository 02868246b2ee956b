"""Codec speed: encoding and decoding 30 KB images of a 10-drone fleet (issue 5/6 load).

The ground station's load target (issue 6) is 10 drones x 10 images/s x 30 KB, about 2,700
datagrams/s. The codec should leave the event loop most of its time, so the targets are ten
times that: decode >= 27,000 datagrams/s and encode >= 1,000 images/s, on one core.
Decoding is measured twice: one datagram per call (``receive_datagram``, as a drone's
companion reads) and in bursts of ``BURST`` (``receive_datagrams``, as the ground station's
socket reader drains them). Prints a table and exits non-zero on a miss.
Run: ``.venv/bin/python benchmarks/bench_protocol.py``.
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
import time

from companion.protocol import Decoder, Encoder
from utility_specs.message import Message, Version

FLEET = 1
KEY = bytes(range(32))
IMAGE_BYTES = 30_000
DRONES = 10
DECODE_TARGET_DPS = 27_000.0
BURST = 64
ENCODE_TARGET_MPS = 1_000.0


def image(sender: str, seq: int, t_gen: float) -> Message:
    return Message(
        sender=sender,
        seq=seq,
        type="image",
        t_gen=t_gen,
        size=IMAGE_BYTES,
        data={"red": 0.2, "object": False, "lat_deg": 50.0, "lon_deg": 19.9, "alt_rel_m": 30.0},
        versions=(
            Version(name="full", size=IMAGE_BYTES, quality=1.0),
            Version(name="half", size=IMAGE_BYTES // 3, quality=0.5),
        ),
        version=0,
    )


def run(
    rounds: int, images_per_drone: int
) -> tuple[list[float], list[float], list[float], int]:
    payload = random.Random(0).randbytes(IMAGE_BYTES)
    encode_rates, decode_rates, burst_rates = [], [], []
    datagram_count = 0
    t0 = 1_700_000_000.0
    for r in range(rounds):
        now = t0 + r * 100.0
        encoders = [Encoder(FLEET, f"drone{d}", KEY) for d in range(DRONES)]
        start = time.perf_counter()
        per_drone = [
            [enc.fragment(image(enc.sender, s, now), payload, now) for s in range(images_per_drone)]
            for enc in encoders
        ]
        encode_s = time.perf_counter() - start
        encode_rates.append(DRONES * images_per_drone / encode_s)
        # Interleave the drones' datagrams as the ground would see them.
        stream = [d for s in range(images_per_drone) for drone in per_drone for d in drone[s]]
        datagram_count = len(stream)
        decoder = Decoder(FLEET, KEY, local_id="ground")
        addr = ("127.0.0.1", 5000)
        start = time.perf_counter()
        for data in stream:
            decoder.receive_datagram(data, addr, now)
            while decoder.next_event() is not None:
                pass
        decode_s = time.perf_counter() - start
        decode_rates.append(len(stream) / decode_s)
        assert decoder.counters["messages"] == DRONES * images_per_drone, decoder.counters
        decoder = Decoder(FLEET, KEY, local_id="ground")
        pairs = [(data, addr) for data in stream]
        start = time.perf_counter()
        for i in range(0, len(pairs), BURST):
            decoder.receive_datagrams(pairs[i : i + BURST], now)
            while decoder.next_event() is not None:
                pass
        burst_rates.append(len(stream) / (time.perf_counter() - start))
        assert decoder.counters["messages"] == DRONES * images_per_drone, decoder.counters
        print(f"round {r + 1}/{rounds}: {len(stream)} datagrams", file=sys.stderr)
    return encode_rates, decode_rates, burst_rates, datagram_count


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--images", type=int, default=20, help="images per drone per round")
    args = parser.parse_args(argv)
    encode_rates, decode_rates, burst_rates, datagrams = run(args.rounds, args.images)
    encode = statistics.median(encode_rates)
    decode = statistics.median(decode_rates)
    burst = statistics.median(burst_rates)
    rows = [
        ("encode", "images/s", encode, ENCODE_TARGET_MPS),
        ("decode", "datagrams/s", decode, DECODE_TARGET_DPS),
        (f"decode x{BURST}", "datagrams/s", burst, DECODE_TARGET_DPS),
    ]
    print(f"{DRONES} drones, {IMAGE_BYTES} B images, {datagrams} datagrams per round (median)")
    print(f"{'step':<10} {'unit':<12} {'measured':>12} {'target':>10}  ok")
    ok = True
    for step, unit, value, target in rows:
        passed = value >= target
        ok &= passed
        verdict = "yes" if passed else "NO"
        print(f"{step:<10} {unit:<12} {value:>12,.0f} {target:>10,.0f}  {verdict}")
    print(f"decode cost per datagram: {1e6 / decode:.1f} us one by one, "
          f"{1e6 / burst:.1f} us in bursts of {BURST}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
