#!/usr/bin/env python3
"""Reference evaluator for RGL `.bsdf` tensor files (Dupuy & Jakob 2018) using
Mitsuba 3's `measured` BSDF plugin.

usage: python mi_eval.py FILE.bsdf DIRS.csv OUT.csv [--wavelengths 400,500,...]

DIRS.csv: rows `wi_x,wi_y,wi_z,wo_x,wo_y,wo_z` (local frame, z = normal); a
non-numeric first line is treated as a header and skipped.

OUT.csv: header line with the channel names, then one row per direction pair:
the BRDF f_r(wi, wo) in 1/sr.  Mitsuba's BSDF::eval (like powitacq's eval)
returns f_r * cos(theta_o), so every value is divided by wo_z.  Pairs with
wi_z <= 0 or wo_z <= 0 are written as 0 (Mitsuba masks them to 0 anyway).

Variant selection (reported on stderr):
  * file has `wavelengths` + `spectra` (spectral RGL file) -> 'scalar_spectral';
    channels are the requested wavelengths (default: the file's own grid),
    column names `400`, `500`, ... (as specgp's sample)
  * file has `rgb` (RGB RGL file) -> 'scalar_rgb'; channels R,G,B.  Mitsuba
    3.x's measured plugin reads the `rgb` field only in RGB variants (it
    interpolates over the 3 channel slices with "wavelength" parameter 0,1,2).
    --wavelengths is ignored (with a warning) for RGB files.

Wavelength handling in the spectral variant: scalar_spectral carries 4
wavelength samples per SurfaceInteraction (si.wavelengths, a 4-vector), and
the measured plugin evaluates its spectra table independently for each of the
4 lanes: spec[i] = spectra(phi_i, theta_i, si.wavelengths[i]; sample), with
*linear interpolation* between the two nearest tabulated wavelengths and
*clamping* to the end values outside the table's range (Marginal2D clips the
parameter weight to [0,1]).  We set all 4 lanes to the same requested
wavelength and take lane 0, so each requested wavelength is one eval() call
and no lane mixing/averaging can occur.  (No spectral upsampling or
colour conversion is involved: the plugin reads the tabulated data directly.)
All arithmetic inside Mitsuba is float32.
"""
import argparse
import struct
import sys

import numpy as np


def tensor_fields(path):
    """Return {name: (dtype_code, offset, shape)} and the raw bytes of a
    Mitsuba 'tensor_file' container."""
    buf = open(path, 'rb').read()
    if buf[:12] != b'tensor_file\0':
        raise SystemExit('%s: not a tensor_file container' % path)
    n, = struct.unpack_from('<I', buf, 14)
    pos, fields = 18, {}
    for _ in range(n):
        ln, = struct.unpack_from('<H', buf, pos); pos += 2
        name = buf[pos:pos + ln].decode(); pos += ln
        ndim, dt, off = struct.unpack_from('<HBQ', buf, pos); pos += 11
        shape = struct.unpack_from('<%dQ' % ndim, buf, pos); pos += 8 * ndim
        fields[name] = (dt, off, shape)
    return fields, buf


def read_dirs(path):
    rows = []
    with open(path) as f:
        for k, line in enumerate(f):
            line = line.strip()
            if not line:
                continue
            parts = line.replace(';', ',').split(',')
            try:
                vals = [float(p) for p in parts]
            except ValueError:
                if k == 0:
                    continue  # header
                raise SystemExit('%s:%d: cannot parse %r' % (path, k + 1, line))
            if len(vals) != 6:
                raise SystemExit('%s:%d: expected 6 values, got %d' % (path, k + 1, len(vals)))
            rows.append(vals)
    return np.array(rows, dtype=np.float64).reshape(-1, 6)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('bsdf')
    ap.add_argument('dirs')
    ap.add_argument('out')
    ap.add_argument('--wavelengths', default=None,
                    help='comma-separated wavelengths in nm (spectral files only; '
                         'default: the file\'s own wavelength grid)')
    a = ap.parse_args()

    fields, buf = tensor_fields(a.bsdf)
    if 'wavelengths' in fields and 'spectra' in fields:
        variant = 'scalar_spectral'
        dt, off, shape = fields['wavelengths']
        assert dt == 10 and len(shape) == 1, 'wavelengths must be float32[n]'
        file_wl = np.frombuffer(buf, np.float32, shape[0], off)
        if a.wavelengths:
            wls = [float(w) for w in a.wavelengths.split(',') if w.strip()]
        else:
            wls = [float(w) for w in file_wl]
        lo, hi = float(file_wl.min()), float(file_wl.max())
        outside = [w for w in wls if w < lo or w > hi]
        if outside:
            print('mi_eval: warning: wavelengths %s outside the file range [%g, %g] nm; '
                  'Mitsuba clamps to the end values' % (outside, lo, hi), file=sys.stderr)
        names = ['%g' % w for w in wls]
    elif 'rgb' in fields:
        variant = 'scalar_rgb'
        if a.wavelengths:
            print('mi_eval: warning: --wavelengths ignored for an RGB file', file=sys.stderr)
        wls = None
        names = ['R', 'G', 'B']
    else:
        raise SystemExit('%s: neither spectra+wavelengths nor rgb field' % a.bsdf)

    import mitsuba as mi
    import drjit as dr
    mi.set_variant(variant)
    mi.set_log_level(mi.LogLevel.Warn)
    bsdf = mi.load_dict({'type': 'measured', 'filename': a.bsdf})
    dirs = read_dirs(a.dirs)
    print('mi_eval: mitsuba %s, drjit %s, variant %s, %s, %d direction pairs, '
          'channels %s' % (mi.__version__, dr.__version__, variant,
                           'spectra+wavelengths path' if wls is not None else 'rgb-field path',
                           len(dirs), ','.join(names) if len(names) <= 12 else
                           '%s..%s (%d)' % (names[0], names[-1], len(names))),
          file=sys.stderr)

    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    out = np.zeros((len(dirs), len(names)))
    for r, (ix, iy, iz, ox, oy, oz) in enumerate(dirs):
        if iz <= 0 or oz <= 0:
            continue
        si.wi = mi.Vector3f(ix, iy, iz)
        wo = mi.Vector3f(ox, oy, oz)
        cos_o = float(mi.Float(oz))  # the same f32 value Mitsuba sees
        if wls is None:
            v = bsdf.eval(ctx, si, wo)
            out[r, :] = [float(v[0]) / cos_o, float(v[1]) / cos_o, float(v[2]) / cos_o]
        else:
            for c, w in enumerate(wls):
                si.wavelengths = mi.Spectrum(w)  # broadcast: all 4 lanes = same nm
                v = bsdf.eval(ctx, si, wo)
                out[r, c] = float(v[0]) / cos_o   # lane 0
    with open(a.out, 'w') as f:
        f.write(','.join(names) + '\n')
        for row in out:
            f.write(','.join('%.9g' % x for x in row) + '\n')


if __name__ == '__main__':
    main()
