"""How steeply Bevy 0.19's TonyMcMapface (then sRGB) turns a change of
linear light into grey levels: for grey stimuli, the display grey level g
(0-255) and dg/d(ln c), beside (g + 14)/2.4, the slope of the sRGB curve
alone. Reads the LUT from bevy_core_pipeline's sources (KTX2, zstd,
Rgb9e5) and samples it as `sample_tony_mc_mapface_lut` does (coordinate
c/(c+1) per channel, trilinear).

    python3 tone_slope.py PATH/TO/tony_mc_mapface.ktx2
"""
import struct
import sys

import numpy as np
import zstandard

N = 48


def load_lut(path):
    data = open(path, "rb").read()
    (vk_format, _type_size, w, h, d, _layers, _faces, levels, scheme) = struct.unpack_from("<9I", data, 12)
    assert (w, h, d) == (N, N, N), (w, h, d)
    offset, length, _raw = struct.unpack_from("<3Q", data, 80)
    level = data[offset:offset + length]
    if scheme == 2:
        level = zstandard.ZstdDecompressor().decompress(level, max_output_size=4 * N ** 3)
    packed = np.frombuffer(level[:4 * N ** 3], dtype="<u4")
    exponent = (packed >> 27).astype(np.int64) - 15 - 9
    channels = [((packed >> shift) & 0x1FF).astype(np.float64) * np.exp2(exponent) for shift in (0, 9, 18)]
    # Red fastest, then green, then blue: index [b, g, r].
    return np.stack(channels, axis=-1).reshape(N, N, N, 3)


def tone_map(lut, rgb):
    uv = np.asarray(rgb, dtype=np.float64)
    uv = uv / (uv + 1.0) * (N - 1)
    i0 = np.clip(np.floor(uv).astype(int), 0, N - 2)
    f = uv - i0
    out = np.zeros(3)
    for db in (0, 1):
        for dg in (0, 1):
            for dr in (0, 1):
                w = (f[2] if db else 1 - f[2]) * (f[1] if dg else 1 - f[1]) * (f[0] if dr else 1 - f[0])
                out += w * lut[i0[2] + db, i0[1] + dg, i0[0] + dr]
    return out


def srgb(x):
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def main():
    lut = load_lut(sys.argv[1])
    print("stimulus   grey g   dg/dln c   (g+14)/2.4   ratio")
    for c in np.exp(np.linspace(np.log(0.005), np.log(0.5), 12)):
        grey = lambda s: 255.0 * srgb(tone_map(lut, [s, s, s])).mean()
        g = grey(c)
        slope = (grey(c * 1.05) - grey(c / 1.05)) / (2 * np.log(1.05))
        print(f"{c:8.4f}   {g:6.1f}   {slope:8.2f}   {(g + 14) / 2.4:10.2f}   {slope / ((g + 14) / 2.4):5.2f}")


if __name__ == "__main__":
    main()
