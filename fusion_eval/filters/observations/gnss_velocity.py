"""GNSS velocity: the receiver's velocity in the world (ENU) frame, ``z = v + R ((w - bg) x l)`` at the
antenna's lever arm ``l`` (``gnss.lever_arm_b_m``, shared with the GNSS position).

The components fused are ``gnss_velocity.components`` (all three, or the horizontal two). Linearised in the
canonical errors (``R = R_hat Exp(dtheta)``, ``w = w_m - bg``)::

    dz/ddv = I,   dz/ddtheta = -R [(w - bg) x l]x,   dz/ddbg = R [l]x

so with no lever arm it observes the velocity alone. Its stream, ``gnss_velocity``, comes from KITTI OXTS
packets (``ve``, ``vn``, and the vertical rate ``vu`` rotated into the world; 1-sigma from
``vel_accuracy``), degraded like the GNSS position because OXTS velocities are the GPS/INS solution
(same receiver epochs by default: ``gnss.rate_hz``, ``gnss.outages_s``; noise ``gnss_velocity.noise_std_mps``
drawn independently of the position's), or from a ``vector_txt`` file ``t_s ve vn vu [std_e std_n std_u]``.
``fusion-eval simulate`` writes such a file for the simulated receiver.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from ...spec import S
from ...datasets import kitti_oxts
from ...datasets.streams import StreamSpec
from ...datasets.vectors import read_vectors
from ...degrade import degrade_vectors, keep_receiver, not_degraded_note
from ...geo import enu_rotation
from ...so3 import euler_rpy_to_matrix, skew
from ...types import VectorSeries
from ..layout import CANONICAL
from .base import N_MAX, TH, V, Bound, Observation, rows_inside

BG = CANONICAL.sl("BG")
WHAT = "GNSS velocity (t_s ve vn vu [std_e std_n std_u], m/s)"


COMPONENTS = {"enu": (0, 1, 2), "en": (0, 1)}


def gnss_velocity(x, clone_p=None, clone_R=None, *, v_obs_w: np.ndarray, std_w: np.ndarray, w_b: np.ndarray,
                  lever_arm_b: np.ndarray, rows: tuple[int, ...] = (0, 1, 2)):
    """ENU velocity of the antenna ``v + R ((w_b - bg) x l)``; ``w_b`` the measured angular rate at the stamp;
    ``rows`` the components observed (0 east, 1 north, 2 up)."""
    wl = np.cross(w_b - x.bg_b, lever_arm_b)
    H = np.zeros((3, N_MAX))
    H[:, V] = np.eye(3)
    H[:, TH] = -x.R_wb @ skew(wl)
    H[:, BG] = x.R_wb @ skew(lever_arm_b)
    r = v_obs_w - (x.v_w_mps + x.R_wb @ wl)
    rows = list(rows)
    return H[rows], r[rows], np.diag(np.asarray(std_w, float)[rows] ** 2)


def _from_oxts(entry: dict, ctx) -> VectorSeries:
    pk = ctx.oxts(entry)
    v = pk.values
    R = euler_rpy_to_matrix(v[:, kitti_oxts.ROLL], v[:, kitti_oxts.PITCH], v[:, kitti_oxts.YAW])
    up = np.einsum("nj,nj->n", R[:, 2, :], v[:, kitti_oxts.VF:kitti_oxts.VU + 1])   # vu rotated: the vertical rate
    enu = np.column_stack([v[:, kitti_oxts.VE], v[:, kitti_oxts.VN], up])          # in the local level frame
    if ctx.origin is not None:                                   # into the origin's ENU frame, the positions' own
        lat0, lon0 = ctx.origin[0], ctx.origin[1]
        enu = np.einsum("nij,nj->ni", enu_rotation(v[:, kitti_oxts.LAT], v[:, kitti_oxts.LON], lat0, lon0), enu)
    acc = kitti_oxts.accuracy(pk, kitti_oxts.VEL_ACC)
    return VectorSeries(t_s=pk.t_s, values=enu,
                        std=np.repeat(acc[:, None], 3, axis=1), filled=pk.filled, source=str(pk.stamps_path),
                        lines=np.arange(1, pk.t_s.size + 1), what="GNSS velocity")


def _from_text(entry: dict, ctx) -> VectorSeries:
    return read_vectors(ctx.path(entry), 3, WHAT, std=entry.get("std_mps"), manifest=ctx.at(entry, "std_mps"), key="std_mps")


def _prepare(series: VectorSeries, cfg: dict, t_ref_s: float, degrade: bool) -> tuple[VectorSeries, dict]:
    c, g = cfg["gnss_velocity"], cfg["gnss"]
    outages = g["outages_s"] if c["outages_s"] == "auto" else c["outages_s"]
    if not degrade:
        # a receiver's velocities get no noise and keep their rate, but outages are the user's experiment: they apply,
        # as to its positions (the velocities inside an outage of the positions were fused: a configuration audit)
        s, info = keep_receiver(series, t_ref_s, outages, c["std_mps"], "mps")
        said = not_degraded_note("gnss_velocity", c, ("rate_hz", "noise_std_mps", "seed"), "a velocity",
                                 "KITTI's OXTS solution is", series.source, "is a receiver's output, used at its own "
                                 "rate and noise (gnss_velocity.outages_s and std_mps do apply)")
        return s, {**info, "warnings": [said] if said else []}
    rate = g["rate_hz"] if c["rate_hz"] == "auto" else c["rate_hz"]
    seed = g["seed"] if c["seed"] is None else c["seed"]
    # a generator of its own: the same seed as the position's noise, drawing independently of it
    s, info = degrade_vectors(series, t_ref_s, rate, c["noise_std_mps"], outages, np.random.default_rng([seed, 1]),
                              c["std_mps"], "mps")
    return s, {**info, "seed": int(seed)}


STREAM = StreamSpec(name="gnss_velocity", what="GNSS velocity", readers={"kitti_oxts": _from_oxts, "vector_txt": _from_text},
                    keys=frozenset({"format", "path", "time_offset_s", "degrade", "std_mps"}),
                    degrade_formats=frozenset({"kitti_oxts"}), implicit_kitti_raw=True, prepare=_prepare)


def _simulate(ctx) -> tuple[dict, dict]:
    """The simulated receiver's velocity at its position epochs (same rate and outages), with white noise."""
    from ...fastfmt import table_text
    from ...simulate.sensors import gnss_epochs

    m, c = ctx.motion, ctx.settings
    idx, keep = gnss_epochs(m, c["gnss"])
    noise = np.asarray(c["gnss"]["velocity_noise_std_mps"], float)
    v = m.v_w_mps[idx] + ctx.rng.standard_normal((idx.size, 3)) * noise
    std = np.tile(np.maximum(noise, 0.01), (int(keep.sum()), 1))    # a receiver never claims zero
    ctx.out.write_text("gnss/velocity.txt", "# t_s ve_mps vn_mps vu_mps std_e_mps std_n_mps std_u_mps (GNSS velocity, ENU)\n"
                       + table_text(np.column_stack([m.t_s[idx][keep], v[keep], std]), [6] + [6] * 6))
    return ({"gnss_velocity": {"format": "vector_txt", "path": "gnss/velocity.txt"}},
            {"gnss_velocity": {"std_mps": "auto"}})


class GnssVelocity(Observation):
    name = "gnss_velocity"
    label = "GNSS velocity"
    also_reads = frozenset({"gnss.lever_arm_b_m"})              # the antenna's, shared with the positions
    dof = 3
    streams = ("gnss_velocity",)
    jumps = True
    blocks = frozenset({"V", "TH", "BG"})
    enabled_by = "filter.use_gnss_velocity"
    gate_key = "gnss_velocity.gate_prob"
    extra_streams = (STREAM,)
    keys = {
        "filter.use_gnss_velocity": S(False, "fuse the GNSS receiver's ENU velocity (stream gnss_velocity; see \"GNSS "
                                             "velocity\")"),
        "gnss_velocity.time_offset_s": S(None, "added to GNSS velocity stamps; null = the manifest's value (default 0)",
                                         "float", nullable=True),
        "gnss_velocity.rate_hz": S("auto", "decimate the GNSS velocity to this rate; 'auto' = gnss.rate_hz (the receiver's "
                                           "epochs); null = keep every one; only for streams the manifest marks 'degrade'",
                                   "float", positive=True, nullable=True, auto=True, reads="data"),
        "gnss_velocity.noise_std_mps": S([0.05, 0.05, 0.1], "white noise added to the GNSS velocity per axis E/N/U, m/s",
                                         nonneg=True, reads="data"),
        "gnss_velocity.outages_s": S("auto", "GNSS velocity outage windows [[start, end], ...], s from the filter's start; "
                                             "'auto' = gnss.outages_s", "windows", auto=True, reads="data"),
        "gnss_velocity.seed": S(None, "seed of the GNSS velocity noise; null = gnss.seed (drawn independently of the "
                                      "position noise)", "int", nullable=True, nonneg=True, reads="data"),
        "gnss_velocity.std_mps": S("auto", "GNSS velocity std given to the filter per axis, m/s; 'auto' = "
                                           "sqrt(reported accuracy^2 + added noise^2)", "vec3", positive=True, auto=True),
        "gnss_velocity.components": S("enu", "components fused: 'enu', or 'en' (horizontal only: a vertical rate made by "
                                             "rotating body-frame velocities carries any pitch misalignment of the velocity's axes)",
                                      choices=tuple(COMPONENTS)),
        "gnss_velocity.gate_prob": S(None, "reject a GNSS velocity whose NIS lies beyond this chi-square probability; "
                                           "null = no gating", "float", positive=True, nullable=True, below_one=True),
    }
    sim_keys = {
        "gnss.velocity_noise_std_mps": S([0.05, 0.05, 0.1], "GNSS velocity white noise per axis E/N/U, m/s (at the "
                                                            "GNSS epochs; gnss/velocity.txt)", nonneg=True),
    }
    simulate = staticmethod(_simulate)

    def bind(self, run, s) -> Bound:
        vs = run.streams[STREAM.name]
        t = run.imu.t_s
        rows = rows_inside(vs.t_s, float(t[run.k_start]), float(t[-1]))
        tv = vs.t_s[rows]
        w = np.column_stack([np.interp(tv, t, run.imu.w_b_rps[:, i]) for i in range(3)])
        lever = np.asarray(s.gnss.lever_arm_b_m, float)
        comp = COMPONENTS[s.gnss_velocity.components]

        def model(j):
            i = rows[j]
            return partial(gnss_velocity, v_obs_w=vs.values[i], std_w=vs.std[i], w_b=w[j], lever_arm_b=lever, rows=comp)

        return Bound(self.name, len(comp), tv, model, gate=self.gate(s, len(comp)))


OBSERVATION = GnssVelocity()
