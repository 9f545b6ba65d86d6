"""What refusing a forged ``map`` message costs a receiver: peak memory (ru_maxrss) and time of one ``decode``.

The map declares a SIDE x SIDE grid whose two channels are valid zlib streams of zeros (a few kB for 49 million cells),
the last occupied cell set where nothing is explored: a receiver that lets the grid's size through refuses it only
after inflating and unpacking both channels. ``bits``: bit-packed channels, as this project sends them; ``bytes``: one
byte a cell (``"z": true``), which a receiver reads too. Run each in a fresh process (ru_maxrss is the process's peak).

    python benchmarks/forged_map.py [bits|bytes] [SIDE]     # SIDE 7000 (49 million cells) by default
"""

from __future__ import annotations

import resource
import sys
import time
import zlib

import msgpack

from cso_runtime.messages import MapMsg, MessageError, decode


def forged_map(side: int, mode: str) -> bytes:
    """The payload of a ``side`` x ``side`` map, its channels coded as ``mode`` (``bits`` or ``bytes``)."""
    n = side * side

    def channel(last: int) -> dict:
        size = (n + 7) // 8 if mode == "bits" else n
        z = zlib.compressobj(9)
        data = z.compress(bytes(size - 1)) + z.compress(bytes([last if mode == "bits" else min(last, 1)])) + z.flush()
        return {"dtype": "bool", "shape": [side, side], "z": "bits" if mode == "bits" else True, "data": data}

    body = {
        "step": 1,
        "episode": 0,
        "geometry": {"resolution_m": 0.05, "shape": [side, side], "origin": [0.0, 0.0]},
        "explored": channel(0),
        "occupied": channel(0x80),
    }
    return msgpack.packb({"schema": "map", "v": MapMsg.VERSION, "body": body}, use_bin_type=True)


def main() -> None:
    mode = sys.argv[1] if len(sys.argv) > 1 else "bits"
    side = int(sys.argv[2]) if len(sys.argv) > 2 else 7000
    payload = forged_map(side, mode)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    try:
        decode(payload, MapMsg)
        said = "ACCEPTED"
    except MessageError as exc:
        said = f"refused: {exc}"
    decode_ms = (time.perf_counter() - t0) * 1000
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(said)
    print(f"{mode} {side} x {side}: payload {len(payload)} B; ru_maxrss +{(after - before) / 1024:.1f} MiB ({before / 1024:.1f} -> {after / 1024:.1f}); decode {decode_ms:.1f} ms")


if __name__ == "__main__":
    main()
