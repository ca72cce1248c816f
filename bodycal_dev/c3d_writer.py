"""Write C3D files (the subset `bodycal_addon.recording.io.c3d` reads: points, labels, units, rate, events;
Intel, DEC or MIPS; int16 or float), so the reader's tests can make files in every processor
format. Development only: not part of the extension."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from bodycal_addon.recording.io.c3d import DEC, INTEL, MIPS


def ieee_to_dec(values: np.ndarray) -> np.ndarray:
    raw = (np.asarray(values, "<f4") * np.float32(4.0)).astype("<f4")[..., None].view(np.uint8)
    return raw[..., [2, 3, 0, 1]].copy()


def write_c3d(path, points: np.ndarray, labels: list[str], rate: float, *, units: str = "mm",
              valid: np.ndarray | None = None, events: list[tuple[str, float]] = (), processor: int = INTEL,
              integer: bool = False, scale: float = 0.1, first_frame: int = 1, y_screen: str = "+Z",
              float_params: dict[str, float] | None = None) -> Path:
    """Write points (F, N, 3) in `units` as a C3D file (no analog data).

    `float_params` ({"GROUP:NAME": value}) writes those parameters as a float32 scalar instead of
    their usual value (or adds them: `ANALOG:RATE`), any value, NaN and infinities included, so the
    reader's tests can feed it what a broken exporter writes. `POINT:DATA_START` written so still
    holds a usable block when its value is finite."""
    path = Path(path)
    pts = np.asarray(points, float)
    f, n = pts.shape[:2]
    valid = np.ones((f, n), bool) if valid is None else np.asarray(valid, bool)
    endian = ">" if processor == MIPS else "<"

    def i16(v):
        return struct.pack(endian + "h", int(v))

    def f32(values):
        values = np.atleast_1d(np.asarray(values, float))
        if processor == DEC:
            return ieee_to_dec(values).tobytes()
        return values.astype(endian + "f4").tobytes()

    records = []
    float_params = {k.upper(): v for k, v in (float_params or {}).items()}

    def group(gid, name):
        body = b"\x00"  # empty description
        records.append(struct.pack("bb", len(name), -gid) + name.encode() + i16(2 + len(body)) + body)

    group_ids = {1: "POINT", 2: "EVENT", 3: "ANALOG"}

    def param(gid, name, dtype, dims, payload):
        key = f"{group_ids[gid]}:{name}"
        if key in float_params:
            dtype, dims, payload = 4, [], f32([float_params.pop(key)])
        body = struct.pack("bB", dtype, len(dims)) + bytes(dims) + payload + b"\x00"
        records.append(struct.pack("bb", len(name), gid) + name.encode() + i16(2 + len(body)) + body)

    def chars(gid, name, strings):
        width = max([len(s) for s in strings] + [1])
        payload = b"".join(s.ljust(width).encode("latin-1") for s in strings)
        param(gid, name, -1, [width, len(strings)], payload)

    group(1, "POINT")
    group(2, "EVENT")
    group(3, "ANALOG")
    param(1, "USED", 2, [], i16(n))
    param(1, "SCALE", 4, [], f32([scale if integer else -abs(scale)]))
    param(1, "RATE", 4, [], f32([rate]))
    param(1, "FRAMES", 2, [], i16(min(f, 32767)))
    param(1, "UNITS", -1, [len(units)], units.encode())
    param(1, "Y_SCREEN", -1, [2], y_screen.encode())
    chars(1, "LABELS", list(labels[:255]))
    if len(labels) > 255:
        chars(1, "LABELS2", list(labels[255:]))
    param(3, "USED", 2, [], i16(0))
    param(2, "USED", 2, [], i16(len(events)))
    if events:
        chars(2, "LABELS", [e[0] for e in events])
        chars(2, "CONTEXTS", ["General"] * len(events))
        times = np.array([[t // 60, t % 60] for _, t in events], float)
        param(2, "TIMES", 4, [2, len(events)], f32(times.ravel()))
    for key in [k for k in float_params if k != "POINT:DATA_START"]:
        gid = {v: k for k, v in group_ids.items()}[key.split(":")[0]]
        param(gid, key.split(":")[1], 4, [], b"")
    pbody = b"".join(records) + b"\x00\x00"

    def data_start_record(block):
        if "POINT:DATA_START" in float_params:
            value = float_params["POINT:DATA_START"]
            return (struct.pack("bb", 10, 1) + b"DATA_START" + i16(9) + struct.pack("bB", 4, 0) + f32([value])
                    + b"\x00")
        return struct.pack("bb", 10, 1) + b"DATA_START" + i16(7) + struct.pack("bB", 2, 0) + i16(block) + b"\x00"

    nblocks = (4 + len(pbody) + len(data_start_record(0)) + 511) // 512
    data_start = 2 + nblocks
    pbody = data_start_record(data_start) + pbody
    psection = bytes([1, 80, nblocks, processor]) + pbody
    psection = psection.ljust(nblocks * 512, b"\x00")

    header = bytearray(512)
    header[0], header[1] = 2, 0x50
    header[2:4] = i16(n)
    header[4:6] = i16(0)
    header[6:8] = i16(first_frame)
    header[8:10] = struct.pack(endian + "H", first_frame + f - 1)
    header[10:12] = i16(0)
    header[12:16] = f32([scale if integer else -abs(scale)])
    header[16:18] = i16(data_start)
    header[18:20] = i16(0)
    header[20:24] = f32([rate])

    block = np.zeros((f, n, 4))
    block[..., :3] = np.where(valid[..., None], pts, 0.0)
    block[..., 3] = np.where(valid, 0.0, -1.0)
    if integer:
        ints = block.copy()
        ints[..., :3] = np.round(block[..., :3] / scale)
        body = ints.astype(endian + "i2").tobytes()
    else:
        body = f32(block.ravel())
    path.write_bytes(bytes(header) + psection + body)
    return path
