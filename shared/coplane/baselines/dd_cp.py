"""GNSS-based cooperative positioning (paper Table I "GNSS-based CP", ref. [10]): DD pseudoranges.

One centralised EKF over every vehicle's state (the Non-CP EKF's state per vehicle, stacked).
Each epoch it fuses (i) every vehicle's absolute pseudoranges, exactly as the Non-CP EKF, and (ii)
for vehicle pairs, double-differenced pseudoranges on their common satellites,

    DD_ab^{ir} = (rho_a^i - rho_b^i) - (rho_a^r - rho_b^r)
               = (|p_a - s_a^i| - |p_b - s_b^i|) - (|p_a - s_a^r| - |p_b - s_b^r|) + e,

with the reference satellite r of each pair and system the common one of highest elevation.
Receiver clocks, satellite clocks and errors common to both receivers (residual ionosphere and
troposphere, orbit, the DGNSS base's own errors) cancel: the DDs carry the pairs' relative
positions. The DD rows use the same corrected rho as the absolute ones (DGNSS-corrected when the
node had corrections).

Covariance of the DDs (the differencing correlation): with M the matrix that maps the stacked
undifferenced pseudoranges of all differenced pairs to their DDs and Sigma = diag(sigma_rx^2) the
receiver-specific undifferenced variances, R_DD = M Sigma M'. It is full: the DDs of a pair share
the reference satellite's two terms, and two pairs sharing a vehicle share that vehicle's terms.
Pairs are the edges of a minimum spanning tree over the predicted baselines (shortest first, up to
`max_baseline_m`): the DDs of any further pair are linear combinations of the tree's (on common
satellites), so adding them would only count the same measurements again (and make R_DD singular).

As in [10] the DD block and the absolute pseudoranges are fused as if independent, although both
come from the same receiver errors; docs/methods.md discusses what that costs.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from coplane.baselines.fleet_filter import EkfConfig, FleetFilter
from coplane.baselines.measurements import VehicleMeasurements, vehicle_measurements
from coplane.baselines.non_cp import gate_pseudoranges, vehicle_estimate
from coplane.baselines.rows import Rows
from coplane.baselines.skeleton import BaselineEstimator, EpochOutcome
from coplane.components import UnionFind
from coplane.estimation.validate import ValidEpoch
from coplane.typing import Mat, Vec


@dataclass(frozen=True)
class DdCpConfig:
    ekf: EkfConfig = field(default_factory=EkfConfig)
    # vehicles farther apart are not differenced: DD-CP needs V2V communication (UWB/DSRC range)
    # and the common-mode errors decorrelate with distance
    max_baseline_m: float = 1000.0


@dataclass(frozen=True)
class DoubleDifference:
    """One DD: pair (a, b), satellite `sat` against the reference `ref` of its system."""

    a: str
    b: str
    sat: str
    ref: str
    value_m: float  # measured DD of rho_c (= rho + c dt_s; the satellite clocks cancel anyway)


def common_references(ma: VehicleMeasurements, mb: VehicleMeasurements) -> dict[str, tuple[str, list[str]]]:
    """Per system with >= 2 common satellites: (reference = highest mean elevation, the others)."""
    ia = {s: k for k, s in enumerate(ma.sats)}
    ib = {s: k for k, s in enumerate(mb.sats)}
    common = sorted(set(ia) & set(ib))
    out: dict[str, tuple[str, list[str]]] = {}
    for sys in sorted({s[0] for s in common}):
        sats = [s for s in common if s[0] == sys]
        if len(sats) < 2:
            continue

        def elev(s: str) -> float:
            e = 0.5 * (ma.elevation[ia[s]] + mb.elevation[ib[s]])
            return float(e) if math.isfinite(e) else -math.inf

        ref = min(sats, key=lambda s: (-elev(s), s))  # highest elevation, then name
        out[sys] = (ref, [s for s in sats if s != ref])
    return out


def double_differences(
    pairs: list[tuple[str, str]], meas: dict[str, VehicleMeasurements]
) -> tuple[list[DoubleDifference], list[tuple[str, str]], Mat]:
    """DDs of the given pairs, the undifferenced (vehicle, satellite) columns and M (DD = M rho).

    R_DD = M diag(sigma_rx^2) M' is then the exact covariance of the DDs given independent
    receiver-specific errors (`dd_covariance`).
    """
    dds: list[DoubleDifference] = []
    cols: dict[tuple[str, str], int] = {}
    entries: list[list[tuple[int, float]]] = []

    def col(v: str, s: str) -> int:
        return cols.setdefault((v, s), len(cols))

    for a, b in pairs:
        ma, mb = meas[a], meas[b]
        ia = {s: k for k, s in enumerate(ma.sats)}
        ib = {s: k for k, s in enumerate(mb.sats)}
        for _sys, (ref, others) in common_references(ma, mb).items():
            for s in others:
                value = (ma.rho_c[ia[s]] - mb.rho_c[ib[s]]) - (ma.rho_c[ia[ref]] - mb.rho_c[ib[ref]])
                dds.append(DoubleDifference(a, b, s, ref, float(value)))
                entries.append([(col(a, s), 1.0), (col(b, s), -1.0), (col(a, ref), -1.0), (col(b, ref), 1.0)])
    m = np.zeros((len(dds), len(cols)))
    for k, row in enumerate(entries):
        for j, v in row:
            m[k, j] += v
    return dds, sorted(cols, key=lambda c: cols[c]), m


def dd_covariance(m: Mat, cols: list[tuple[str, str]], meas: dict[str, VehicleMeasurements]) -> Mat:
    """R_DD = M diag(sigma_rx^2) M' (receiver-specific sigmas of the undifferenced columns)."""
    var = np.empty(len(cols))
    for j, (v, s) in enumerate(cols):
        mv = meas[v]
        var[j] = mv.sigma_rx[mv.sats.index(s)] ** 2
    return (m * var) @ m.T


def spanning_pairs(
    positions: dict[str, Vec], candidates: list[tuple[str, str]], max_baseline_m: float
) -> list[tuple[str, str]]:
    """Minimum spanning forest (Kruskal) over the candidate pairs by predicted baseline length."""
    edges = []
    for a, b in candidates:
        d = float(np.linalg.norm(positions[a] - positions[b]))
        if d <= max_baseline_m:
            edges.append((d, a, b))
    uf = UnionFind(positions)
    return sorted((a, b) for _, a, b in sorted(edges) if uf.union(a, b))


class DdCpEkf(BaselineEstimator):
    """Estimator: the centralised DD-CP EKF over the whole fleet."""

    def __init__(self, config: DdCpConfig | None = None) -> None:
        super().__init__()
        self.config = config or DdCpConfig()
        self.filter = FleetFilter(self.config.ekf)

    def solve(self, valid: ValidEpoch, out: EpochOutcome) -> None:
        try:
            self._step(valid, out)
        except Exception as exc:  # never raise on data: restart the fleet filter
            self.filter = FleetFilter(self.config.ekf)
            out.rejected["filter_failure"] += 1
            out.estimates.clear()
            for vid in sorted({*valid.vehicles, *valid.skipped}):
                out.skipped.setdefault(vid, f"filter failure ({type(exc).__name__}): restarts next epoch")
        out.n_clusters = 1 if out.estimates else 0

    def _step(self, valid: ValidEpoch, out: EpochOutcome) -> None:
        t = valid.time
        rejected, counts = out.rejected, out.counts
        filt = self.filter
        filt.predict(t)
        meas: dict[str, VehicleMeasurements] = {}
        for vid, vehicle in valid.vehicles.items():
            m = vehicle_measurements(vehicle)
            reason = filt.prepare_vehicle(m, t, rejected)
            if reason is not None:
                out.skipped[vid] = reason
                continue
            meas[vid] = m
        filt.drop_stale(t)
        # gate every vehicle before building rows: a restart re-indexes the state
        good = {vid: gate_pseudoranges(filt, m, t, rejected) for vid, m in sorted(meas.items())}

        rows = Rows(len(filt.x))
        for vid in sorted(good):
            filt.pseudorange_rows(rows, good[vid])
        keep = list(range(len(rows.groups)))
        n_dd0 = len(rows.groups)
        self._dd_rows(rows, good, counts)
        n_dd1 = len(rows.groups)
        for vid in sorted(meas):
            filt.velocity_rows(rows, meas[vid])
        g = filt.gate(rows, range(n_dd0, len(rows.groups)))
        keep += g.accepted
        for i in g.rejected:
            rejected[f"{rows.groups[i][1]}_gate"] += 1
        if not filt.update(rows, sorted(keep)):
            rejected["update_failure"] += 1
            keep = []
        dd_per_vehicle: Counter[str] = Counter()
        for i in keep:
            counts[rows.groups[i][1]] += 1
            if n_dd0 <= i < n_dd1:
                for v in rows.groups[i][2]:
                    dd_per_vehicle[v] += 1
        for vid in sorted(meas):
            used = good[vid] if keep else good[vid].subset([])
            if len(used):
                filt.last_gnss[vid] = t
            out.estimates[vid] = vehicle_estimate(filt, vid, t, meas[vid], used)
        counts["dd_vehicles"] = len(dd_per_vehicle)

    def _dd_rows(self, rows: Rows, good: dict[str, VehicleMeasurements], counts: Counter[str]) -> None:
        """The DD block of the spanning-tree pairs, one gating group per DD, one R block."""
        filt = self.filter
        vids = sorted(v for v, m in good.items() if len(m) >= 2)
        positions = {v: filt.position(v) for v in vids}
        cands = [
            (a, b) for i, a in enumerate(vids) for b in vids[i + 1 :] if common_references(good[a], good[b])
        ]
        pairs = spanning_pairs(positions, cands, self.config.max_baseline_m)
        if not pairs:
            return
        dds, cols, m = double_differences(pairs, good)
        if not dds:
            return
        counts["dd_pairs"] += len(pairs)
        r = dd_covariance(m, cols, good)
        nu, hs = [], []
        for dd in dds:
            pred, ha, hb = dd_model(dd, good[dd.a], good[dd.b], positions[dd.a], positions[dd.b])
            h = np.zeros(rows.n_state)
            h[filt.pos_idx(dd.a)] = ha
            h[filt.pos_idx(dd.b)] = hb
            nu.append(dd.value_m - pred)
            hs.append(h)
        i0 = len(rows.groups)
        rows.add(nu, hs, r, "dd_pseudorange", (), per_row=True)
        for k, dd in enumerate(dds):  # record the pair of each DD for the per-vehicle counts
            idx, kind, _ = rows.groups[i0 + k]
            rows.groups[i0 + k] = (idx, kind, (dd.a, dd.b))


def dd_model(
    dd: DoubleDifference, ma: VehicleMeasurements, mb: VehicleMeasurements, pa: Vec, pb: Vec
) -> tuple[float, Vec, Vec]:
    """Predicted DD at positions pa, pb and its Jacobians d/dpa, d/dpb (each vehicle's own
    satellite positions: they are in that receiver's reception frame)."""
    sa_i, sa_r = ma.sat_pos[ma.sats.index(dd.sat)], ma.sat_pos[ma.sats.index(dd.ref)]
    sb_i, sb_r = mb.sat_pos[mb.sats.index(dd.sat)], mb.sat_pos[mb.sats.index(dd.ref)]
    ra_i, ra_r = pa - sa_i, pa - sa_r
    rb_i, rb_r = pb - sb_i, pb - sb_r
    na_i, na_r, nb_i, nb_r = (float(np.linalg.norm(v)) for v in (ra_i, ra_r, rb_i, rb_r))
    pred = (na_i - nb_i) - (na_r - nb_r)
    return pred, ra_i / na_i - ra_r / na_r, -(rb_i / nb_i - rb_r / nb_r)
