#!/usr/bin/env python3
"""X helpers of the window test, with the standard library only: reads
`xwd -root` dumps (32-bit ZPixmap, what Xvfb's 24-bit screens give), writes
them as PNG, compares regions of them, and asks a window to
close as a window manager's close button does (WM_DELETE_WINDOW).

  xtool.py png DUMP.xwd OUT.png
  xtool.py differ A.xwd B.xwd X Y W H      # share of pixels that differ in a region
  xtool.py brightness DUMP.xwd X Y W H     # mean of a region's channels, 0-1
  xtool.py spread DUMP.xwd X Y W H         # standard deviation of its pixels' brightness
  xtool.py close WINDOW_ID                 # WM_DELETE_WINDOW to the window
"""
import ctypes
import struct
import sys
import zlib


def read_xwd(path):
    """(width, height, rows of (r, g, b) tuples) of an xwd dump."""
    data = open(path, "rb").read()
    fields = struct.unpack(">25I", data[:100])
    header_size, _version, pixmap_format, _depth, width, height = fields[:6]
    byte_order, bits_per_pixel, bytes_per_line = fields[7], fields[11], fields[12]
    red_mask, green_mask, blue_mask = fields[14], fields[15], fields[16]
    ncolors = fields[19]
    if pixmap_format != 2 or bits_per_pixel != 32:
        raise SystemExit(f"{path}: expected a 32-bit ZPixmap dump, got format {pixmap_format}, {bits_per_pixel} bpp")
    offset = header_size + 12 * ncolors
    order = "<" if byte_order == 0 else ">"

    def channel(value, mask):
        shift = (mask & -mask).bit_length() - 1
        return (value & mask) >> shift

    rows = []
    for y in range(height):
        start = offset + y * bytes_per_line
        values = struct.unpack(f"{order}{width}I", data[start:start + 4 * width])
        rows.append([(channel(v, red_mask), channel(v, green_mask), channel(v, blue_mask)) for v in values])
    return width, height, rows


def write_png(path, width, height, rows):
    raw = b"".join(b"\x00" + bytes(c for pixel in row for c in pixel) for row in rows)

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    open(path, "wb").write(png)


def differ(rows_a, rows_b, x, y, w, h):
    """Share of the region's pixels whose colour differs by more than 8 in a channel."""
    pairs = [(a, b) for row_a, row_b in zip(rows_a[y:y + h], rows_b[y:y + h])
             for a, b in zip(row_a[x:x + w], row_b[x:x + w])]
    changed = sum(1 for a, b in pairs if max(abs(p - q) for p, q in zip(a, b)) > 8)
    return changed / max(len(pairs), 1)


def brightness(rows, x, y, w, h):
    """Mean of the region's colour channels, in [0, 1]."""
    values = [c for row in rows[y:y + h] for pixel in row[x:x + w] for c in pixel[:3]]
    return sum(values) / (255 * max(len(values), 1))


def spread(rows, x, y, w, h):
    """Standard deviation of the region's pixels' brightness (mean channel,
    0-1): 0 for one flat colour, such as a window's clear colour before its
    first frame."""
    values = [sum(pixel[:3]) / (3 * 255) for row in rows[y:y + h] for pixel in row[x:x + w]]
    mean = sum(values) / max(len(values), 1)
    return (sum((v - mean) ** 2 for v in values) / max(len(values), 1)) ** 0.5


class XClientMessageEvent(ctypes.Structure):
    _fields_ = [("type", ctypes.c_int), ("serial", ctypes.c_ulong), ("send_event", ctypes.c_int),
                ("display", ctypes.c_void_p), ("window", ctypes.c_ulong), ("message_type", ctypes.c_ulong),
                ("format", ctypes.c_int), ("data", ctypes.c_long * 5)]


class XEvent(ctypes.Union):
    _fields_ = [("xclient", XClientMessageEvent), ("pad", ctypes.c_long * 24)]


def close(window):
    """Sends WM_DELETE_WINDOW, as a window manager does when the user closes
    the window (`xdotool windowclose` destroys it instead)."""
    x11 = ctypes.cdll.LoadLibrary("libX11.so.6")
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XInternAtom.restype = ctypes.c_ulong
    x11.XInternAtom.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int]
    x11.XSendEvent.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_long, ctypes.c_void_p]
    x11.XFlush.argtypes = [ctypes.c_void_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    display = x11.XOpenDisplay(None)
    if not display:
        raise SystemExit("cannot open the X display")
    event = XEvent()
    event.xclient.type = 33  # ClientMessage
    event.xclient.window = window
    event.xclient.message_type = x11.XInternAtom(display, b"WM_PROTOCOLS", 0)
    event.xclient.format = 32
    event.xclient.data[0] = x11.XInternAtom(display, b"WM_DELETE_WINDOW", 0)
    event.xclient.data[1] = 0  # CurrentTime
    if not x11.XSendEvent(display, window, 0, 0, ctypes.byref(event)):
        raise SystemExit("XSendEvent failed")
    x11.XFlush(display)
    x11.XCloseDisplay(display)


if __name__ == "__main__":
    command = sys.argv[1] if len(sys.argv) > 1 else ""
    if command == "png":
        write_png(sys.argv[3], *read_xwd(sys.argv[2]))
    elif command == "differ":
        _, _, rows_a = read_xwd(sys.argv[2])
        _, _, rows_b = read_xwd(sys.argv[3])
        print(f"{differ(rows_a, rows_b, *(int(v) for v in sys.argv[4:8])):.6f}")
    elif command == "brightness":
        _, _, rows = read_xwd(sys.argv[2])
        print(f"{brightness(rows, *(int(v) for v in sys.argv[3:7])):.6f}")
    elif command == "spread":
        _, _, rows = read_xwd(sys.argv[2])
        print(f"{spread(rows, *(int(v) for v in sys.argv[3:7])):.6f}")
    elif command == "close":
        close(int(sys.argv[2], 0))
    else:
        raise SystemExit(__doc__)
