"""Which shipped sensor recorded these scans: `--sensor` becomes optional where the data tells.

A scan's signature is measured, not assumed: its ring count (when a ring field is present and not
all zero), the elevation of its lowest and highest returns, its horizontal span, the azimuth step
between successive returns of one ring, and the scan rate. A profile fits when the signature lies
within its geometry; the firing rate (azimuth step x scan rate) is compared rather than either
alone, since a VLP-16 may spin at 5-20 Hz. Exactly one fit is chosen; none or several is an
error that lists every candidate and why it fits or not.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from forestslam.errors import InputError
from forestslam.io.scan import Scan
from forestslam.sensors.profile import SensorProfile, available_profiles, load_profile

log = logging.getLogger(__name__)

ELEVATION_TOL_DEG = 1.5
SPAN_TOL_DEG = 20.0
FIRING_RATE_TOL = 0.3
MIN_RANGE_M = 1.0


@dataclass(frozen=True)
class Signature:
    rings: int | None
    elevation_deg: tuple[float, float]
    span_deg: float
    azimuth_step_deg: float | None
    rate_hz: float | None

    def describe(self) -> str:
        parts = [f"{self.rings} rings" if self.rings else "no ring field"]
        parts.append("elevations {:.1f} to {:.1f} deg".format(*self.elevation_deg))
        parts.append(f"span {self.span_deg:.0f} deg")
        if self.azimuth_step_deg:
            parts.append(f"azimuth step {self.azimuth_step_deg:.3f} deg")
        if self.rate_hz:
            parts.append(f"{self.rate_hz:.1f} Hz")
        return ", ".join(parts)


def signature(scans: list[Scan]) -> Signature:
    """The measured geometry of a few scans (the first ones of a recording)."""
    pts = [s.points[np.linalg.norm(s.points, axis=1) > MIN_RANGE_M] for s in scans]
    allp = np.concatenate(pts) if pts else np.zeros((0, 3))
    if len(allp) < 100:
        raise InputError("too few returns to identify the sensor: give --sensor")
    horizontal = np.hypot(allp[:, 0], allp[:, 1])
    elevation = np.degrees(np.arctan2(allp[:, 2], horizontal))
    azimuth = np.degrees(np.arctan2(allp[:, 1], allp[:, 0])) % 360.0
    occupied = np.bincount(azimuth.astype(int) % 360, minlength=360) > 0
    rings = [s.ring for s in scans if s.ring is not None and len(s.ring) and s.ring.max() > 0]
    n_rings = int(max(r.max() for r in rings)) + 1 if rings else None
    stamps = [s.stamp for s in scans]
    rate = (
        (len(stamps) - 1) / (stamps[-1] - stamps[0])
        if len(stamps) > 1 and stamps[-1] > stamps[0]
        else None
    )
    return Signature(
        n_rings,
        (float(np.percentile(elevation, 0.2)), float(np.percentile(elevation, 99.8))),
        float(occupied.sum()),
        _azimuth_step(scans[0]) if rings else None,
        rate,
    )


def _azimuth_step(scan: Scan) -> float | None:
    """Median azimuth difference between successive returns of one ring (order of firing)."""
    steps = []
    for ring in np.unique(scan.ring):
        p = scan.points[scan.ring == ring]
        az = np.unwrap(np.arctan2(p[:, 1], p[:, 0]))
        d = np.abs(np.diff(az))
        d = d[(d > 0) & (d < np.radians(2.0))]
        if len(d) > 20:
            steps.append(np.degrees(np.median(d)))
    return float(np.median(steps)) if steps else None


def misfit(profile: SensorProfile, sig: Signature) -> list[str]:
    """Why the signature does not fit the profile ([] when it does)."""
    why = []
    if sig.rings is not None and sig.rings != profile.channels:
        why.append(f"{profile.channels} channels, not {sig.rings}")
    lo, hi = profile.vertical_fov_deg
    if abs(sig.elevation_deg[0] - lo) > ELEVATION_TOL_DEG:
        why.append(f"lowest beam at {lo:g} deg, data at {sig.elevation_deg[0]:.1f}")
    if sig.elevation_deg[1] > hi + ELEVATION_TOL_DEG:
        why.append(f"highest beam at {hi:g} deg, data up to {sig.elevation_deg[1]:.1f}")
    if abs(min(sig.span_deg, 360.0) - profile.horizontal_fov_deg) > SPAN_TOL_DEG:
        why.append(f"spans {profile.horizontal_fov_deg:g} deg, data {sig.span_deg:.0f}")
    if sig.azimuth_step_deg and sig.rate_hz:
        data, expected = (
            sig.azimuth_step_deg * sig.rate_hz,
            profile.azimuth_resolution_deg * profile.rate_hz,
        )
        if abs(data / expected - 1.0) > FIRING_RATE_TOL:
            why.append(f"fires {expected:.2f} deg*Hz, data {data:.2f}")
    return why


def identify(scans: list[Scan], names: list[str] | None = None) -> SensorProfile:
    """The one shipped scanning profile that fits `scans`; InputError lists the candidates."""
    profiles = [load_profile(n) for n in (names or available_profiles())]
    candidates = [p for p in profiles if p.kind in ("spinning", "solid_state")]
    sig = signature(scans)
    fits = {p.name: misfit(p, sig) for p in candidates}
    chosen = [p for p in candidates if not fits[p.name]]
    if len(chosen) == 1:
        log.info("sensor identified as %s from the data (%s)", chosen[0].name, sig.describe())
        return chosen[0]
    listing = "; ".join(f"{n}: {', '.join(w) or 'fits'}" for n, w in fits.items())
    what = "several sensors fit" if chosen else "no shipped sensor fits"
    raise InputError(
        f"{what} the data ({sig.describe()}): {listing}. Give --sensor (for an accumulated "
        "map, a TLS scan or a crop of either: --sensor map or tls)"
    )


def identify_stream(scans, first: int = 5):
    """(profile, scans): the shipped profile the first scans of an iterator fit (logged by
    `identify`), and the same scans with those put back in front."""
    import itertools

    head = list(itertools.islice(scans, first))
    if not head:
        raise InputError("no scans to identify the sensor from: give --sensor")
    return identify(head), itertools.chain(head, scans)
