#!/usr/bin/env python3
"""Reference CIEDE2000 values for crates/render/tests/colour_properties.rs.

An implementation independent of `render::colour::delta_e_2000`: the hue difference and the
mean hue are taken as circular quantities through atan2 instead of the case analysis of Sharma,
Wu and Dalal (2005), and CIELAB uses the CIE's epsilon/kappa form. It reproduces Sharma's
Table 1 (checked below) and prints the values the Rust test hard-codes: pairs whose mean hue
wraps through 0, sits near 275 degrees, or has hue sums either side of 360 degrees; a colour on
the negative a axis against a neighbour; two pairs of linear sRGB colours.

Usage (standard library only): python3 scripts/ciede2000_reference.py
"""
import math

# Linear sRGB -> XYZ (D65), the 7-decimal matrix of render::colour::SRGB_TO_XYZ.
SRGB_TO_XYZ = [
    [0.4124564, 0.3575761, 0.1804375],
    [0.2126729, 0.7151522, 0.0721750],
    [0.0193339, 0.1191920, 0.9503041],
]


def lab_of_linear_srgb(rgb):
    """CIELAB relative to the matrix's white (its image of (1, 1, 1))."""
    white = [sum(row) for row in SRGB_TO_XYZ]
    xyz = [sum(SRGB_TO_XYZ[i][j] * rgb[j] for j in range(3)) for i in range(3)]
    eps, kappa = 216 / 24389, 24389 / 27

    def f(t):
        return t ** (1 / 3) if t > eps else (kappa * t + 16) / 116

    fx, fy, fz = (f(xyz[i] / white[i]) for i in range(3))
    return (116 * fy - 16, 500 * (fx - fy), 200 * (fy - fz))


def delta_e_2000(p, q):
    (l1, a1, b1), (l2, a2, b2) = p, q
    c1, c2 = math.hypot(a1, b1), math.hypot(a2, b2)
    cb7 = ((c1 + c2) / 2) ** 7
    g = 0.5 * (1 - math.sqrt(cb7 / (cb7 + 25**7)))
    a1p, a2p = (1 + g) * a1, (1 + g) * a2
    c1p, c2p = math.hypot(a1p, b1), math.hypot(a2p, b2)
    tau = 2 * math.pi
    h1 = math.atan2(b1, a1p) % tau if c1p > 0 else 0.0
    h2 = math.atan2(b2, a2p) % tau if c2p > 0 else 0.0
    chromatic = c1p * c2p > 0
    # Signed hue difference in (-pi, pi] and circular mean hue in [0, 2 pi).
    dh = math.atan2(math.sin(h2 - h1), math.cos(h2 - h1)) if chromatic else 0.0
    big_dh = 2 * math.sqrt(c1p * c2p) * math.sin(dh / 2)
    if chromatic:
        hb = math.atan2(math.sin(h1) + math.sin(h2), math.cos(h1) + math.cos(h2)) % tau
    else:
        hb = h1 + h2
    deg = math.pi / 180
    t = (
        1
        - 0.17 * math.cos(hb - 30 * deg)
        + 0.24 * math.cos(2 * hb)
        + 0.32 * math.cos(3 * hb + 6 * deg)
        - 0.20 * math.cos(4 * hb - 63 * deg)
    )
    dtheta = 30 * deg * math.exp(-(((hb / deg - 275) / 25) ** 2))
    cbp7 = ((c1p + c2p) / 2) ** 7
    rc = 2 * math.sqrt(cbp7 / (cbp7 + 25**7))
    l50 = ((l1 + l2) / 2 - 50) ** 2
    sl = 1 + 0.015 * l50 / math.sqrt(20 + l50)
    sc = 1 + 0.045 * (c1p + c2p) / 2
    sh = 1 + 0.015 * (c1p + c2p) / 2 * t
    rt = -math.sin(2 * dtheta) * rc
    tl, tc, th = (l2 - l1) / sl, (c2p - c1p) / sc, big_dh / sh
    return math.sqrt(tl * tl + tc * tc + th * th + rt * tc * th)


def polar(lightness, chroma, hue_deg):
    h = math.radians(hue_deg)
    return (lightness, chroma * math.cos(h), chroma * math.sin(h))


if __name__ == "__main__":
    # A few rows of Sharma's Table 1 (pairs 1, 12, 15, 16, 21, 25), to 4 decimals.
    for p, q, want in [
        ((50, 2.6772, -79.7751), (50, 0, -82.7485), 2.0425),
        ((50, 2.49, -0.001), (50, -2.49, 0.0012), 7.2195),
        ((50, -0.001, 2.49), (50, 0.0011, -2.49), 4.7461),
        ((50, 2.5, 0), (50, 0, -2.5), 4.3065),
        ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644),
        ((22.7233, 20.0904, -46.694), (23.0331, 14.973, -42.5619), 2.0373),
    ]:
        assert round(delta_e_2000(p, q), 4) == want, (p, q, want)
    for p, q in [
        (polar(50, 20, 350), polar(50, 30, 30)),
        (polar(60, 30, 2), polar(60, 20, 188)),
        (polar(55, 20, 85), polar(55, 30, 268)),
        ((50, -20, 0), (50, -20, 1e-6)),
    ]:
        print(repr(p), repr(q), repr(delta_e_2000(p, q)))
    for a, b in [((1, 0, 0), (0, 0, 1)), ((0.2, 0.5, 0.1), (0.25, 0.45, 0.12))]:
        print(a, b, repr(delta_e_2000(lab_of_linear_srgb(a), lab_of_linear_srgb(b))))
