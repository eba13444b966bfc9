"""The compiled loops of :mod:`.kernels`, at module level: numba's cache keys a function defined inside
another by the contents of its closure, and a closure holding other compiled functions (the helpers
these kernels call) pickles differently in every process, so each process compiled them again (about
4 s; a warm demo spent them in every worker).  Imported only by ``kernels.kernels()``: importing this
module imports numba.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

jit = njit(cache=True, nogil=True, boundscheck=False)


@jit
def _outline_distance(px, py, vertices, s, e):
    """Distance of (px, py) to the closed outline vertices[s:e] (geometry.polygons.outline_distance's expressions)."""
    best = np.inf
    for i in range(s, e):
        j = i + 1 if i + 1 < e else s
        ax, ay = vertices[i, 0], vertices[i, 1]
        abx, aby = vertices[j, 0] - ax, vertices[j, 1] - ay
        length2 = max(abx * abx + aby * aby, 1e-18)
        apx, apy = px - ax, py - ay
        t = min(max((apx * abx + apy * aby) / length2, 0.0), 1.0)
        gx, gy = apx - t * abx, apy - t * aby
        d = math.sqrt(gx * gx + gy * gy)
        if d < best:
            best = d
    return best


@jit
def outline_distances(points, vertices, starts, pair_point, pair_polygon, out):
    """out[p] = min(out[p], distance of point p to polygon n's outline) for each pair (p, n)."""
    for k in range(pair_point.shape[0]):
        p, n = pair_point[k], pair_polygon[k]
        best = _outline_distance(points[p, 0], points[p, 1], vertices, starts[n], starts[n + 1])
        if best < out[p]:
            out[p] = best


@jit
def nearest_outlines_within(points, vertices, starts, bounds, within, origin, size, nx, ny, cell_starts,
                            cell_polygons, out):
    """out[p]: the least distance of point p to the outlines of the polygons whose bounds, widened by
    ``within``, hold it (inf: none); the pairs lanes.ScoreMap.distance_to_drivable's numpy test admits.
    The candidates are those listed in the grid cells that the point's square of half side ``within``
    meets, the square a micrometre wider (a polygon the bounds test admits then meets it, whatever
    the rounding of the subtractions), each measured once however many of those cells list it."""
    seen = np.full(bounds.shape[0], -1, dtype=np.int64)
    reach = within + 1e-6
    for p in range(points.shape[0]):
        px, py = points[p, 0], points[p, 1]
        best = np.inf
        i0 = max(np.floor((px - reach - origin[0]) / size), 0.0)
        i1 = min(np.floor((px + reach - origin[0]) / size), nx - 1.0)
        j0 = max(np.floor((py - reach - origin[1]) / size), 0.0)
        j1 = min(np.floor((py + reach - origin[1]) / size), ny - 1.0)
        for i in range(int(i0), int(i1) + 1):
            for j in range(int(j0), int(j1) + 1):
                cell = i * int(ny) + j
                for k in range(cell_starts[cell], cell_starts[cell + 1]):
                    n = cell_polygons[k]
                    if seen[n] == p:
                        continue
                    seen[n] = p
                    if (px >= bounds[n, 0] - within and px <= bounds[n, 2] + within
                            and py >= bounds[n, 1] - within and py <= bounds[n, 3] + within):
                        d = _outline_distance(px, py, vertices, starts[n], starts[n + 1])
                        if d < best:
                            best = d
        out[p] = best


@jit
def containing_in_grid(points, xi, yi, yj, slope, band_first, band_count, band_height, band_starts, band_edges,
                       bounds, origin, size, nx, ny, cell_starts, cell_polygons, out, held, touched):
    """out[p, n]: point p in polygon n (lanes._containing's crossing-number rule), testing only the
    polygons listed in the point's grid cell (every polygon whose bounds meet the cell: the bounds
    test admits no other), and of each only the edges of the point's band (lanes._bands: the others
    cross no horizontal line through it).  held[p]: some polygon holds point p; touched[n]: polygon n
    holds some point (out's rows' and columns' any, without reading it again)."""
    for p in range(points.shape[0]):
        px, py = points[p, 0], points[p, 1]
        fx, fy = np.floor((px - origin[0]) / size), np.floor((py - origin[1]) / size)
        if not (fx >= 0.0 and fx < nx and fy >= 0.0 and fy < ny):
            continue
        cell = int(fx) * int(ny) + int(fy)
        for k in range(cell_starts[cell], cell_starts[cell + 1]):
            n = cell_polygons[k]
            if px >= bounds[n, 0] and px <= bounds[n, 2] and py >= bounds[n, 1] and py <= bounds[n, 3]:
                band = 0.0
                if band_height[n] > 0:
                    band = min(max(np.floor((py - bounds[n, 1]) / band_height[n]), 0.0), band_count[n] - 1.0)
                slot = band_first[n] + int(band)
                count = 0
                for i in range(band_starts[slot], band_starts[slot + 1]):
                    e = band_edges[i]
                    if ((yi[e] <= py) != (yj[e] <= py)) and px < xi[e] + (py - yi[e]) * slope[e]:
                        count += 1
                if (count & 1) == 1:
                    out[p, n] = True
                    held[p] = True
                    touched[n] = True


@jit
def _overlap(ax, ay, ca, sa, al, aw, bx, by, cb, sb, bl, bw):
    """geometry.boxes.oriented_boxes_overlap for one pair (half extents given)."""
    dx, dy = bx - ax, by - ay
    cos_rel = abs(ca * cb + sa * sb)
    sin_rel = abs(ca * sb - sa * cb)
    return (abs(dx * ca + dy * sa) <= al + cos_rel * bl + sin_rel * bw + 0.0
            and abs(dy * ca - dx * sa) <= aw + sin_rel * bl + cos_rel * bw + 0.0
            and abs(dx * cb + dy * sb) <= bl + cos_rel * al + sin_rel * aw + 0.0
            and abs(dy * cb - dx * sb) <= bw + sin_rel * al + cos_rel * aw + 0.0)


@jit
def box_contacts(available, xy, yaw, length, width, ego_xy, ego_cos, ego_sin, ego_length, ego_width, ego_radius):
    """(frames, cols) of the available cells whose box meets the ego's (collisions.contacts: nuPlan's
    bounding-circle precheck, centres nearer than the half diagonals' sum, then the boxes' overlap,
    touching counts), frame by frame.  The float32 cells widen to float64 before any arithmetic."""
    t, a = available.shape
    frames = np.empty(t * a, dtype=np.int64)
    cols = np.empty(t * a, dtype=np.int64)
    m = 0
    for f in range(t):
        ex, ey = ego_xy[f, 0], ego_xy[f, 1]
        for c in range(a):
            if not available[f, c]:
                continue
            ax, ay = np.float64(xy[f, c, 0]), np.float64(xy[f, c, 1])
            al, aw = np.float64(length[f, c]), np.float64(width[f, c])
            # most cells are far: a bound of the precheck's radius (al + aw is at least its hypotenuse, and
            # a micrometre covers the roundings) against the larger coordinate distance, without a root
            reach = (ego_radius + (al + aw)) / 2.0 + 1e-6
            if abs(ax - ex) >= reach or abs(ay - ey) >= reach:
                continue
            radius = (ego_radius + math.hypot(aw, al)) / 2.0
            if not math.hypot(ax - ex, ay - ey) < radius:
                continue
            h = np.float64(yaw[f, c])
            if _overlap(ex, ey, ego_cos[f], ego_sin[f], 0.5 * ego_length, 0.5 * ego_width, ax, ay, math.cos(h),
                        math.sin(h), 0.5 * al, 0.5 * aw):
                frames[m] = f
                cols[m] = c
                m += 1
    return frames[:m], cols[:m]


@jit
def first_meeting(frame, ego_xy, e_cos, e_sin, e_step, e_sweep, e_length, e_width, a_xy, a_cos, a_sin, a_step,
                  a_sweep, a_length, a_width, half_reach, steps, out):
    """out[k]: for pair k (the ego at frame[k], agent k), the first step s - 1 (s in 1..steps) at which
    their boxes, moved s steps on, overlap; -1 if none, or if the boxes swept over the whole horizon
    do not overlap (ttc._first_meetings)."""
    el, ew = 0.5 * e_length, 0.5 * e_width
    for k in range(frame.shape[0]):
        f = frame[k]
        ex, ey, ec, es, sx, sy = ego_xy[f, 0], ego_xy[f, 1], e_cos[f], e_sin[f], e_step[f, 0], e_step[f, 1]
        ax, ay, ac, as_, tx, ty = a_xy[k, 0], a_xy[k, 1], a_cos[k], a_sin[k], a_step[k, 0], a_step[k, 1]
        al, aw = 0.5 * a_length[k], 0.5 * a_width[k]
        out[k] = -1
        if not _overlap(ex + half_reach * sx, ey + half_reach * sy, ec, es, 0.5 * (e_length + e_sweep[f]),
                        0.5 * (e_width + 0.0), ax + half_reach * tx, ay + half_reach * ty, ac, as_,
                        0.5 * (a_length[k] + a_sweep[k]), 0.5 * (a_width[k] + 0.0)):
            continue
        for s in range(1, steps + 1):
            g = float(s)
            if _overlap(ex + g * sx, ey + g * sy, ec, es, el, ew, ax + g * tx, ay + g * ty, ac, as_, al, aw):
                out[k] = s - 1
                break


@jit
def meeting_candidates(available, moving, token, hit_frame, hit_token, ego_xy, e_cos, e_sin, e_step, e_sweep,
                       e_length, e_width, a_xy, a_yaw, a_velocity, a_static, a_length, a_width, horizon, step,
                       half_reach, margin, slack):
    """(frames, cols) of the cells the ego could meet within ``horizon`` seconds: available, the ego
    ``moving`` at that frame, the agent not hit before (``hit_token[j]`` from frame ``hit_frame[j]`` on),
    and a superset of those :func:`first_meeting` finds a meeting for, kept by two tests no meeting
    fails.  First, the ego's box swept over the horizon (each half extent ``slack`` metres longer)
    comes within the agent's reach of its centre: half its length plus width (at least its half
    diagonal), its travel at |vx| + |vy| (at least its speed) and ``margin`` metres, a circle holding
    its own swept box.  Then the two swept boxes overlap, ``slack`` longer,
    with this kernel's cosine and sine of the agent's heading, not numpy's as first_meeting takes
    them: they may differ in the last bit, which moves a box by far less than ``slack``."""
    t, a = available.shape
    frames = np.empty(t * a, dtype=np.int64)
    cols = np.empty(t * a, dtype=np.int64)
    m = 0
    for f in range(t):
        if not moving[f]:
            continue
        ec, es = e_cos[f], e_sin[f]
        bx, by = ego_xy[f, 0] + half_reach * e_step[f, 0], ego_xy[f, 1] + half_reach * e_step[f, 1]
        hl, hw = 0.5 * (e_length + e_sweep[f]) + slack, 0.5 * e_width + slack
        for c in range(a):
            if not available[f, c]:
                continue
            hit = False
            for j in range(hit_frame.shape[0]):
                if f >= hit_frame[j] and token[f, c] == hit_token[j]:
                    hit = True
            if hit:
                continue
            # float64 of float32 cells (a log's), exactly, before any arithmetic: as ttc computes
            ax, ay = np.float64(a_xy[f, c, 0]), np.float64(a_xy[f, c, 1])
            vx, vy = np.float64(a_velocity[f, c, 0]), np.float64(a_velocity[f, c, 1])
            al, aw = np.float64(a_length[f, c]), np.float64(a_width[f, c])
            # bounds of the half diagonal and the speed without a square root: most cells end here
            radius = 0.5 * (al + aw) + (0.0 if a_static[f, c] else horizon * (abs(vx) + abs(vy))) + margin
            dx, dy = ax - bx, ay - by
            along = max(abs(dx * ec + dy * es) - hl, 0.0)
            across = max(abs(dy * ec - dx * es) - hw, 0.0)
            if along * along + across * across > radius * radius:
                continue
            speed = 0.0 if a_static[f, c] else math.sqrt(vx * vx + vy * vy)
            yaw = np.float64(a_yaw[f, c])
            ac, as_ = math.cos(yaw), math.sin(yaw)
            tx, ty = speed * step * ac, speed * step * as_
            sweep = 2.0 * half_reach * math.sqrt(tx * tx + ty * ty)
            if _overlap(bx, by, ec, es, hl, hw, ax + half_reach * tx, ay + half_reach * ty, ac, as_,
                        0.5 * (al + sweep) + slack, 0.5 * aw + slack):
                frames[m] = f
                cols[m] = c
                m += 1
    return frames[:m], cols[:m]


@jit
def _along(px, py, vertices, s, e, cumulative):
    """Arc length along the line vertices[s:e] (arc lengths at its vertices cumulative[s:e]) of the
    point's nearest point on it (lanes.project's expressions)."""
    best, best_t, best_len2, best_i = np.inf, 0.0, 1.0, s
    for i in range(s, e - 1):
        ax, ay = vertices[i, 0], vertices[i, 1]
        abx, aby = vertices[i + 1, 0] - ax, vertices[i + 1, 1] - ay
        length2 = max(abx * abx + aby * aby, 1e-18)
        apx, apy = px - ax, py - ay
        t = min(max((apx * abx + apy * aby) / length2, 0.0), 1.0)
        gx, gy = apx - t * abx, apy - t * aby
        d2 = gx * gx + gy * gy
        if d2 < best:  # the first of equally near segments, as numpy's argmin
            best, best_t, best_len2, best_i = d2, t, length2, i
    return cumulative[best_i] + best_t * math.sqrt(best_len2)


@jit
def project(points, line_of, vertices, starts, cumulative, out):
    """out[p]: arc length along line line_of[p] (vertices[starts[n]:starts[n + 1]], arc lengths at its
    vertices cumulative[same]) of point p's nearest point on it (lanes.project)."""
    for p in range(points.shape[0]):
        n = line_of[p]
        out[p] = _along(points[p, 0], points[p, 1], vertices, starts[n], starts[n + 1], cumulative)


@jit
def directions(points, line_of, vertices, starts, cumulative, headings, out):
    """out[p]: the heading of line line_of[p]'s segment at point p's projection (lanes.ScoreMap.directions:
    the last segment starting at or before it); line n's segment headings are headings[starts[n] - n:
    starts[n + 1] - n - 1]."""
    for p in range(points.shape[0]):
        n = line_of[p]
        s, e = starts[n], starts[n + 1]
        if e - s < 2:  # no segment, no heading
            out[p] = np.nan
            continue
        along = _along(points[p, 0], points[p, 1], vertices, s, e, cumulative)
        segment = -1
        for i in range(s, e):  # searchsorted(side="right") - 1: the vertices at or before it, less one
            if cumulative[i] <= along:
                segment += 1
            else:
                break
        segment = min(max(segment, 0), e - s - 2)
        out[p] = headings[s - n + segment]
