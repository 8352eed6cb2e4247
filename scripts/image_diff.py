#!/usr/bin/env python3
"""Mean absolute RGB difference (0-255) between PNG pictures of one size.

    python3 scripts/image_diff.py REFERENCE.png OTHER.png [OTHER.png ...]

Prints one JSON object: for each OTHER, `mean_abs` (mean over pixels and
the three colour channels of |OTHER - REFERENCE|) and `p99_abs` (99th
percentile of the per-pixel mean over channels). Pure Python (zlib), so it
runs wherever the repository's scripts do; 8-bit RGB or RGBA PNGs only.
"""
import json
import struct
import sys
import zlib


def read_png(path):
    """(width, height, rows of RGB triples flattened) of an 8-bit PNG."""
    data = open(path, "rb").read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise SystemExit(f"{path}: not a PNG")
    pos, idat, header = 8, b"", None
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos : pos + 8])
        body = data[pos + 8 : pos + 8 + length]
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    width, height, depth, color, _, _, interlace = header
    if depth != 8 or color not in (2, 6) or interlace:
        raise SystemExit(f"{path}: only 8-bit RGB/RGBA, non-interlaced")
    channels = 3 if color == 2 else 4
    raw = zlib.decompress(idat)
    stride = width * channels
    previous = bytearray(stride)
    pixels = []
    for y in range(height):
        start = y * (stride + 1)
        kind, line = raw[start], bytearray(raw[start + 1 : start + 1 + stride])
        for i in range(stride):
            a = line[i - channels] if i >= channels else 0
            b = previous[i]
            c = previous[i - channels] if i >= channels else 0
            if kind == 1:
                line[i] = (line[i] + a) & 255
            elif kind == 2:
                line[i] = (line[i] + b) & 255
            elif kind == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif kind == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                predictor = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                line[i] = (line[i] + predictor) & 255
        previous = line
        for x in range(width):
            pixels.append(tuple(line[x * channels : x * channels + 3]))
    return width, height, pixels


def main():
    if len(sys.argv) < 3:
        raise SystemExit(__doc__)
    reference = read_png(sys.argv[1])
    out = {"reference": sys.argv[1], "pictures": {}}
    for path in sys.argv[2:]:
        other = read_png(path)
        if other[:2] != reference[:2]:
            raise SystemExit(f"{path}: {other[:2]} is not the reference's size {reference[:2]}")
        per_pixel = sorted(
            sum(abs(p - q) for p, q in zip(a, b)) / 3.0 for a, b in zip(reference[2], other[2])
        )
        out["pictures"][path] = {
            "mean_abs": round(sum(per_pixel) / len(per_pixel), 3),
            "p99_abs": round(per_pixel[int(0.99 * (len(per_pixel) - 1))], 3),
        }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
