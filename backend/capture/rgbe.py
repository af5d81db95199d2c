"""Radiance RGBE (.hdr) reader, flat and run-length encoded scanlines."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError


def read_rgbe(path: str | Path) -> np.ndarray:
    path = Path(path)
    data = path.read_bytes()
    bad = lambda what: InputError(path, f"not a Radiance HDR file ({what})",  # noqa: E731
                                  "re-export the environment map as .hdr or .exr")
    if not (data.startswith(b"#?RADIANCE") or data.startswith(b"#?RGBE")):
        raise bad("missing #?RADIANCE header")
    pos = 0
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            raise bad("truncated header")
        line = data[pos:end].strip()
        pos = end + 1
        if line.startswith(b"FORMAT=") and line != b"FORMAT=32-bit_rle_rgbe":
            raise bad(f"unsupported {line.decode(errors='replace')}")
        if line.startswith(b"-Y") or line.startswith(b"+Y"):
            parts = line.split()
            if len(parts) != 4 or parts[0] != b"-Y" or parts[2] != b"+X":
                raise bad(f"unsupported orientation {line.decode(errors='replace')}")
            height, width = int(parts[1]), int(parts[3])
            break
    buf = np.frombuffer(data, dtype=np.uint8, offset=pos)
    out = np.empty((height, width, 4), dtype=np.uint8)
    i = 0
    try:
        for y in range(height):
            if width >= 8 and width < 32768 and buf[i] == 2 and buf[i + 1] == 2 and not (buf[i + 2] & 0x80):
                i += 4
                for c in range(4):
                    x = 0
                    row = out[y, :, c]
                    while x < width:
                        count = int(buf[i])
                        i += 1
                        if count > 128:
                            count -= 128
                            row[x:x + count] = buf[i]
                            i += 1
                        else:
                            row[x:x + count] = buf[i:i + count]
                            i += count
                        x += count
            else:
                out[y] = buf[i:i + 4 * width].reshape(width, 4)
                i += 4 * width
    except (IndexError, ValueError) as err:
        raise bad("truncated pixel data") from err
    e = out[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0).astype(np.float32)
    return out[..., :3].astype(np.float32) * scale[..., None]
