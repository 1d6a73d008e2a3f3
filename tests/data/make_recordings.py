"""Make the small committed recordings the replay tests use (run on purpose only):

    python -m tests.data.make_recordings      # from the repository root

wall_clean.lpr: 1 s of sim://wall (64 points, 20 Hz) recorded with `laserpi record`.
wall_corrupt.lpr: the same bytes with deterministic damage - bit flips, dropped bytes, inserted
junk, runs of zeros, chunk times unchanged - and its last record cut short.
"""

from __future__ import annotations

import random
from pathlib import Path

from device.cli import main
from host_sdk.recording import RecordingWriter, read_recording

HERE = Path(__file__).parent


def corrupt(src: Path, dst: Path, seed: int = 8) -> None:
    header, records = read_recording(src)
    rng = random.Random(seed)
    records = list(records)
    out = []
    for i, (t, chunk) in enumerate(records):
        b = bytearray(chunk)
        if i < 4:  # keep the handshake (INFO) intact: without it no scan can be placed
            out.append((t, chunk))
            continue
        if i % 6 == 2 and len(b) > 10:
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)  # bit flip
        if i % 10 == 3 and len(b) > 10:
            del b[rng.randrange(len(b))]  # dropped byte
        if i % 13 == 4:
            b[len(b) // 2:len(b) // 2] = bytes(rng.randrange(1, 256) for _ in range(5))  # inserted junk
        if i % 11 == 7:
            b[len(b) // 3:len(b) // 3] = bytes(20)  # run of zeros
        out.append((t, bytes(b)))
    dst.unlink(missing_ok=True)
    with RecordingWriter(dst, header) as w:
        for t, b in out:
            w.write(t, b)
    data = dst.read_bytes()
    dst.write_bytes(data[:-7])  # the recorder was killed mid-record


if __name__ == "__main__":
    clean = HERE / "wall_clean.lpr"
    clean.unlink(missing_ok=True)
    main(["record", "--port", "sim://wall?distance=1.2&points=64&rate=20&seed=5", "--seconds", "1",
          "--out", str(clean)])
    corrupt(clean, HERE / "wall_corrupt.lpr")
