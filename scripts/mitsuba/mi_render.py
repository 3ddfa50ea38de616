#!/usr/bin/env python3
"""Render a unit sphere with Mitsuba 3's `measured` BSDF (an RGL .bsdf file).

usage: python mi_render.py FILE.bsdf OUT.png [--spp 256] [--size 256] [--depth 3]

Variant: scalar_spectral for files with `wavelengths`+`spectra`, scalar_rgb for
files with an `rgb` field (Mitsuba reads those only in RGB variants).
Scene: unit sphere at the origin, perspective camera on +z looking at it, a dim
constant environment (radiance 0.1) plus a directional light from the upper
left (45 deg from the view axis, towards the upper left -- the same direction
as specgp render's default --light 45,135).  Emitters are given as RGB white,
which Mitsuba's spectral variants turn into a D65 spectrum (so white paper
renders white in both variants).  Path tracer, max_depth 3.
Writes OUT.png (Mitsuba's sRGB conversion, 8 bit), OUT-stem.npy (linear RGB,
float32, HxWx3) and OUT-stem_mask.npy (pixels whose centre ray hits the sphere).
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from mi_eval import tensor_fields  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('bsdf')
    ap.add_argument('out')
    ap.add_argument('--spp', type=int, default=256)
    ap.add_argument('--size', type=int, default=256)
    ap.add_argument('--depth', type=int, default=3)
    ap.add_argument('--env', type=float, default=0.1)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--sun', type=float, default=3.0, help='irradiance of the directional light')
    a = ap.parse_args()

    fields, _ = tensor_fields(a.bsdf)
    if 'spectra' in fields and 'wavelengths' in fields:
        variant = 'scalar_spectral'
    elif 'rgb' in fields:
        variant = 'scalar_rgb'
    else:
        raise SystemExit('%s: neither spectra+wavelengths nor rgb' % a.bsdf)

    import mitsuba as mi
    mi.set_variant(variant)
    mi.set_log_level(mi.LogLevel.Warn)
    T = mi.ScalarTransform4f

    cam_dist, fov = 4.0, 32.0
    # direction *towards* the light: 45 deg from the view axis (+z), to the upper left
    th, ph = np.radians(45.0), np.radians(135.0)
    to_light = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    scene = mi.load_dict({
        'type': 'scene',
        'integrator': {'type': 'path', 'max_depth': a.depth},
        'sensor': {
            'type': 'perspective', 'fov': fov, 'fov_axis': 'x',
            'to_world': T().look_at(origin=[0, 0, cam_dist], target=[0, 0, 0], up=[0, 1, 0]),
            'sampler': {'type': 'multijitter', 'sample_count': a.spp},
            'film': {'type': 'hdrfilm', 'width': a.size, 'height': a.size,
                     'pixel_format': 'rgb', 'rfilter': {'type': 'gaussian'}},
        },
        'sphere': {'type': 'sphere', 'center': [0, 0, 0], 'radius': 1.0,
                   'bsdf': {'type': 'measured', 'filename': os.path.abspath(a.bsdf)}},
        'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': [a.env] * 3}},
        'sun': {'type': 'directional', 'direction': (-to_light).tolist(),
                'irradiance': {'type': 'rgb', 'value': [a.sun] * 3}},
    })
    t0 = time.time()
    img = mi.render(scene, seed=a.seed)
    dt = time.time() - t0
    arr = np.array(img, dtype=np.float32)[:, :, :3]
    bmp = mi.Bitmap(arr, mi.Bitmap.PixelFormat.RGB)
    bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True).write(a.out)

    # mask: pixel-centre rays that hit the sphere (same camera model as above;
    # Mitsuba's image x axis: check by the light position in the picture)
    n = a.size
    t = np.tan(np.radians(fov) / 2)
    c = (np.arange(n) + 0.5) / n * 2 - 1
    X, Y = np.meshgrid(c * t, -c * t)
    d = np.stack([X, Y, -np.ones_like(X)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    o = np.array([0, 0, cam_dist])
    b = d @ o
    disc = b * b - (o @ o - 1.0)
    mask = disc > 0.02  # pixel centres on the sphere, 1-2 px in from the silhouette
    stem = os.path.splitext(a.out)[0]
    np.save(stem + '.npy', arr)
    np.save(stem + '_mask.npy', mask)
    bad = ~np.isfinite(arr)
    sph = arr[mask]
    print('%s: %s, %dx%d, %d spp, depth %d, %.1f s; NaN/inf %d, negative %d, '
          'sphere mean RGB %s, max %.3g' % (
              os.path.basename(a.bsdf), variant, n, n, a.spp, a.depth, dt, bad.sum(),
              (arr < 0).sum(), np.round(sph.mean(0), 4).tolist(), sph.max()))


if __name__ == '__main__':
    main()
