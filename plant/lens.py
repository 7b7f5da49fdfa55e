"""The camera's lens model: OpenCV's plumb-bob distortion (k1, k2, p1, p2, k3) and its
inverse, on normalised image coordinates (see :mod:`plant.camera`)."""
from __future__ import annotations

import numpy as np


def distort(x, y, d):
    """Distorted normalised coords of undistorted (x, y) under d = (k1, k2, p1, p2, k3)."""
    k1, k2, p1, p2, k3 = d
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return xd, yd


def undistort(xd, yd, d, k):
    """Normalised undistorted coords whose distortion gives (xd, yd); nan if none.

    OpenCV's iterative ``undistortPoints`` gives the start, Newton steps with the
    analytic Jacobian polish it to < 1e-12 (normalised units)."""
    x, y = xd.copy(), yd.copy()
    try:        # imported here: a plant whose cameras have no distortion never loads OpenCV
        import cv2
    except ImportError:      # opencv is optional: Newton steps alone then
        cv2 = None
    if cv2 is not None:
        pts = (np.stack([xd * k[0, 0] + k[0, 2], yd * k[1, 1] + k[1, 2]], -1)
               .reshape(-1, 1, 2).astype(np.float64))
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-14)
        und = cv2.undistortPoints(pts, k, np.asarray(d, float), criteria=crit).reshape(-1, 2)
        if np.all(np.isfinite(und)):
            x, y = und[:, 0].copy(), und[:, 1].copy()
    k1, k2, p1, p2, k3 = d
    with np.errstate(all="ignore"):
        for _ in range(50):
            fx, fy = distort(x, y, d)
            ex, ey = fx - xd, fy - yd
            err = np.hypot(ex, ey)
            if not (np.nanmax(err) > 1e-13):
                break
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
            a = radial + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
            b = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
            e = radial + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
            det = a * e - b * b
            x = x - (e * ex - b * ey) / det
            y = y - (a * ey - b * ex) / det
        fx, fy = distort(x, y, d)
        bad = ~(np.hypot(fx - xd, fy - yd) < 1e-9) | ~np.isfinite(x) | ~np.isfinite(y)
    x[bad] = np.nan
    y[bad] = np.nan
    return x, y
