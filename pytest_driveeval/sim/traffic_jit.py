"""The traffic step of :func:`pytest_driveeval.sim.agents.step_traffic`, written for numba.

Plain Python functions over scalars and arrays that :mod:`.episodes_jit`
compiles (never called uncompiled: the numpy path is agents.step_traffic
itself).  Each is the numpy path's float64 expressions in the same order, so
numba (no fastmath: no fused multiply-adds) gives the same bits: ``_max``,
``_min`` and ``clip`` are numpy's ``maximum``, ``minimum`` and ``clip`` for
floats, ``_free`` and ``_interaction`` IDM's terms (:func:`~.agents.idm_free`
for exponent 4, :func:`~.agents.idm_interaction`).
"""
from __future__ import annotations

import numpy as np

__all__ = ["CONSTANTS", "HALF_LENGTH", "HALF_WIDTH", "clip", "constants", "traffic_kernel"]

#: the traffic model's and the boxes' constants, in the order :func:`constants` packs them
CONSTANTS = ("max_accel", "comfort_decel", "max_brake", "time_headway", "min_gap", "lane_change_gain",
             "max_imposed_braking", "lane_change_duration", "ready", "yield_margin", "merge_zone", "idm_denominator",
             "half_length", "half_width", "dt")
(_A, _B, _BRAKE, _T, _S0, _GAIN, _IMPOSED, _DURATION, _READY, _YIELD_MARGIN, _MERGE_ZONE, _DEN, _HL,
 _HW, _DT) = range(len(CONSTANTS))
HALF_LENGTH, HALF_WIDTH = _HL, _HW


def constants(model, size: np.ndarray, dt: float) -> np.ndarray:
    """:data:`CONSTANTS` of a TrafficModel, box ``size`` (length, width) and step, computed as the numpy path does."""
    c = np.empty(len(CONSTANTS))
    c[[_A, _B, _BRAKE, _T, _S0, _GAIN, _IMPOSED, _DURATION, _YIELD_MARGIN, _MERGE_ZONE]] = (
        model.max_accel, model.comfort_decel, model.max_brake, model.time_headway, model.min_gap,
        model.lane_change_gain, model.max_imposed_braking, model.lane_change_duration, model.yield_margin,
        model.merge_zone)
    c[_READY] = model.lane_change_duration + model.lane_change_cooldown
    c[_DEN] = 2.0 * np.sqrt(model.max_accel * model.comfort_decel)
    c[_HL], c[_HW], c[_DT] = 0.5 * size[0], 0.5 * size[1], dt
    return c


def _max(a, b):
    """np.maximum of two floats (NaN from the first wins, as numpy's)."""
    return a if (a >= b or a != a) else b


def _min(a, b):
    return a if (a <= b or a != a) else b


def clip(x, lo, hi):
    """np.clip with scalar bounds."""
    m = x if (x > lo or x != x) else lo
    return m if (m < hi or m != m) else hi


def _free(c, v, desired):
    """agents.idm_free for exponent 4."""
    r = abs(v / desired)
    r = r * r
    return c[_A] * (1.0 - r * r)


def _interaction(c, v, lead_v, gap):
    """agents.idm_interaction."""
    dv = v - lead_v
    desired_gap = c[_S0] + _max(0.0, v * c[_T] + v * dv / c[_DEN])
    q = desired_gap / _max(gap, 0.01)
    return q * q


def traffic_kernel(c, a0, u0, heading0, same_heading, widths, lengths, end_s, left_of, right_of,
                   lane, s, d, tspeed, desired, offset, ctime, yield_to, valid, xy, yaw, speed, outcome,
                   n_lane, n_s, n_d, n_speed, n_offset, n_time, n_yield, n_valid, atan_y, atan_x):
    """agents.step_traffic for the running episodes (``outcome`` 0), up to the arctan2 of the new headings
    (its arguments go to ``atan_y``, ``atan_x``); the others keep their state."""
    e_n, a_n = lane.shape
    l_n = len(widths)
    ps = np.empty((a_n, l_n))
    pd = np.empty((a_n, l_n))
    half = np.empty((a_n, l_n))
    v_al = np.empty((a_n, l_n))
    free_al = np.empty((a_n, l_n))
    occ = np.zeros((a_n, l_n), np.bool_)
    wish = np.zeros((a_n, l_n), np.bool_)
    looked = np.empty(3, np.int64)
    cos_l, sin_l = np.empty(l_n), np.empty(l_n)
    accel = np.empty(3)
    best = np.empty(a_n)
    side = np.empty(a_n, np.int64)
    new_yield = np.empty(a_n, np.int64)
    acc0 = np.empty(a_n)
    hl, hw = c[_HL], c[_HW]
    for e in range(e_n):
        if outcome[e] != 0:  # ended: keeps its state
            for i in range(a_n):
                n_lane[e, i], n_s[e, i], n_d[e, i], n_speed[e, i] = lane[e, i], s[e, i], d[e, i], tspeed[e, i]
                n_offset[e, i], n_time[e, i], n_yield[e, i] = offset[e, i], ctime[e, i], yield_to[e, i]
                n_valid[e, i] = valid[e, i]
                atan_y[e, i], atan_x[e, i] = 0.0, 2.0
            continue
        # Every agent on every lane (Road.footprint), who occupies and who wishes to enter which.
        for j in range(a_n):
            vehicle = valid[e, j] and j > 0
            present = vehicle or j == 0
            if not present:  # padding, or gone: it occupies nothing and wishes nothing
                for l in range(l_n):
                    occ[j, l], wish[j, l] = False, False
                continue
            target = -1
            if vehicle:
                es = end_s[lane[e, j]]
                if np.isfinite(es) and s[e, j] > es - c[_MERGE_ZONE]:
                    target = left_of[lane[e, j]]
            for l in range(l_n):
                rx = xy[e, j, 0] - a0[l, 0]
                ry = xy[e, j, 1] - a0[l, 1]
                ps[j, l] = rx * u0[l, 0] + ry * u0[l, 1]
                pd[j, l] = u0[l, 0] * ry - u0[l, 1] * rx
                if same_heading[l] == l:  # lanes of one heading share the cosine and sine
                    rel = yaw[e, j] - heading0[l]
                    cos_l[l], sin_l[l] = np.cos(rel), np.sin(rel)
                else:
                    cos_l[l], sin_l[l] = cos_l[same_heading[l]], sin_l[same_heading[l]]
                cos_rel = cos_l[l]
                along, across = abs(cos_rel), abs(sin_l[l])
                clearance = abs(pd[j, l]) - 0.5 * widths[l] - (across * hl + along * hw)
                half[j, l] = along * hl + across * hw
                v_al[j, l] = speed[e, j] * cos_rel
                free_al[j, l] = _free(c, v_al[j, l], desired[e, j])
                occ[j, l] = present and ((vehicle and lane[e, j] == l) or clearance < 0.0)
                if j == 0:
                    wish[j, l] = not occ[j, l] and clearance < c[_YIELD_MARGIN]
                else:
                    wish[j, l] = vehicle and target == l
        # IDM on the own lane and both neighbours, MOBIL's gain and safety there.
        for i in range(a_n):
            best[i] = -np.inf
            side[i] = 1
            new_yield[i] = -1
            if not (valid[e, i] and i > 0):
                continue
            own = lane[e, i]
            looked[0], looked[1], looked[2] = own, left_of[own], right_of[own]
            v = tspeed[e, i]
            free = _free(c, v, desired[e, i])
            for k in range(3):
                exists = looked[k] >= 0
                if k > 0 and not (exists and ctime[e, i] >= c[_READY]):  # no change: accel[k] is not used
                    accel[k] = 0.0
                    continue
                lk = looked[k] if exists else 0
                self_s, self_half, self_v = ps[i, lk], half[i, lk], v_al[i, lk]
                strongest = 0.0
                yielded_max = 0.0
                yielded_arg = 0
                letting = False
                safe = True
                # Only agents that occupy or wish to enter lane lk can lead or follow there; the terms
                # are computed where the numpy path uses them, which leaves its values as they are.
                for j in range(a_n):
                    occupies, wishes = occ[j, lk], k == 0 and wish[j, lk]
                    if not (occupies or wishes):
                        continue
                    ahead_by = ps[j, lk] - self_s
                    gap = abs(ahead_by) - half[j, lk] - self_half
                    if ahead_by >= 0.0 and j != i:
                        lead = _interaction(c, v, v_al[j, lk], gap)
                        if occupies:
                            strongest = _max(strongest, lead)
                        if wishes and (free - c[_A] * lead >= -c[_IMPOSED] or yield_to[e, i] == j):
                            letting = True
                            if lead > yielded_max:
                                yielded_max, yielded_arg = lead, j
                    elif k > 0 and safe and ahead_by < 0.0 and occupies:
                        follow = free_al[j, lk] - c[_A] * _interaction(c, v_al[j, lk], self_v, gap)
                        if follow < -c[_IMPOSED]:
                            safe = False
                if k == 0:
                    strongest = _max(strongest, yielded_max)
                    new_yield[i] = yielded_arg if letting else -1
                end_gap = end_s[lk] - self_s - self_half
                accel[k] = free - c[_A] * (strongest + _interaction(c, v, 0.0, end_gap))
                if k > 0:
                    gain = accel[k] - accel[0]
                    if (safe and accel[k] >= -c[_IMPOSED] and gain > c[_GAIN] and ctime[e, i] >= c[_READY]
                            and gain > best[i]):
                        best[i], side[i] = gain, k
            acc0[i] = accel[0]
        first = 0
        for i in range(1, a_n):
            if best[i] > best[first]:
                first = i
        # Motion along the lane the vehicle ends the step on.
        for i in range(a_n):
            if not (valid[e, i] and i > 0):
                n_lane[e, i], n_s[e, i], n_d[e, i], n_speed[e, i] = lane[e, i], s[e, i], d[e, i], tspeed[e, i]
                n_offset[e, i], n_time[e, i], n_yield[e, i] = offset[e, i], ctime[e, i], -1
                n_valid[e, i] = valid[e, i]
                atan_y[e, i], atan_x[e, i] = 0.0, _max(tspeed[e, i], 2.0)
                continue
            v = tspeed[e, i]
            a = clip(acc0[i], -c[_BRAKE], c[_A])
            v_next = v + a * c[_DT]
            if v_next < 0.0:
                travel = v * v / (2.0 * _max(-a, 1e-9))
            else:
                travel = 0.5 * (v + _max(v_next, 0.0)) * c[_DT]
            v_next = _max(v_next, 0.0)
            starts = i == first and np.isfinite(best[i])
            own = lane[e, i]
            if starts:
                new_lane = left_of[own] if side[i] == 1 else right_of[own]
                s_next = ps[i, new_lane] + travel
                off = pd[i, new_lane]
                t_change = 0.0 + c[_DT]
            else:
                new_lane = own
                s_next = s[e, i] + travel
                off = offset[e, i]
                t_change = ctime[e, i] + c[_DT]
            x = _min(t_change / c[_DURATION], 1.0)
            n_lane[e, i], n_s[e, i], n_speed[e, i] = new_lane, s_next, v_next
            n_d[e, i] = off * (1.0 - x * x * (3.0 - 2.0 * x))
            n_offset[e, i], n_time[e, i] = off, t_change
            n_yield[e, i] = -1 if starts else new_yield[i]
            n_valid[e, i] = s_next <= lengths[new_lane] + hl
            atan_y[e, i] = -off * 6.0 * x * (1.0 - x) / c[_DURATION]
            atan_x[e, i] = _max(v_next, 2.0)
