"""Signed distances between convex cores, batched over any leading dimensions, pure torch.

Every shape is a convex core (a point, a segment, or a polytope: vertices, triangles, edges)
grown by a radius, so two shapes are ``radius_a + radius_b`` closer than their cores. The
distance of two cores is the least over their feature pairs (vertex–triangle, edge–edge), which
is exact for disjoint cores; overlapping cores get minus their penetration depth along the
best face normal of either (exact where a vertex or an edge enters a face, the usual shallow
contact) or between two crossing edges.

Each least or greatest over features goes through :func:`select`: a hard choice (the default;
the gradient is that of the chosen feature, exact almost everywhere and switching where two
features tie), or, with ``smoothing`` [m], softmin weights ``softmax(−d/smoothing)`` that blend
the features within a few ``smoothing`` of the best, so the distance and its gradient are
smooth at those switches, at an error bounded by ``smoothing · log(features)``.
"""

from __future__ import annotations

import torch

EDGE_POINTS = 4
"""Edge pairs, the closest first, whose witnesses are offered as patch points."""

TINY = 1e-12
"""Guards divisions by a squared length [m²]."""


def select(values: torch.Tensor, dim: int, smoothing: float | None, largest: bool = False):
    """Weights over ``dim`` that pick the least (or ``largest``) of ``values``: one-hot of the
    best, or the softmin weights at length ``smoothing``; returns ``(value, weights)``."""
    signed = values if largest else -values
    if smoothing is None:
        weights = torch.nn.functional.one_hot(signed.argmax(dim), values.shape[dim])
        weights = weights.to(values.dtype).movedim(-1, dim)
    else:
        weights = torch.softmax(signed / smoothing, dim)
    return (weights * values).sum(dim), weights


def pick(weights: torch.Tensor, items: torch.Tensor, dim: int) -> torch.Tensor:
    """``Σ weights · items`` over ``dim`` of ``items (..., k, 3)`` (``dim`` counts ``weights``)."""
    return (weights.unsqueeze(-1) * items).sum(dim - 1 if dim < 0 else dim)


def safe_norm(x: torch.Tensor) -> torch.Tensor:
    """``‖x‖`` over the last dimension, with a finite gradient at zero (where it is 1e-15)."""
    return torch.sqrt((x * x).sum(-1) + 1e-30)


def closest_on_triangle(p, a, b, c) -> torch.Tensor:
    """Closest point ``(..., 3)`` of the triangle ``a, b, c`` to ``p`` (all broadcast ``(..., 3)``),
    by the triangle's Voronoi regions (vertex, edge, face)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    bp = p - b
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    cp = p - c
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    # the face region: barycentric coordinates (1 − v − w, v, w)
    total = (va + vb + vc).clamp_min(TINY)
    v, w = vb / total, vc / total
    point = a + ab * v.unsqueeze(-1) + ac * w.unsqueeze(-1)
    # edge regions, then vertex regions, overriding in turn
    t_ab = d1 / (d1 - d3).clamp_min(TINY)
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    point = torch.where(on_ab.unsqueeze(-1), a + ab * t_ab.unsqueeze(-1), point)
    t_ac = d2 / (d2 - d6).clamp_min(TINY)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    point = torch.where(on_ac.unsqueeze(-1), a + ac * t_ac.unsqueeze(-1), point)
    t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6)).clamp_min(TINY)
    on_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    point = torch.where(on_bc.unsqueeze(-1), b + (c - b) * t_bc.unsqueeze(-1), point)
    point = torch.where(((d1 <= 0) & (d2 <= 0)).unsqueeze(-1), a, point)
    point = torch.where(((d3 >= 0) & (d4 <= d3)).unsqueeze(-1), b, point)
    point = torch.where(((d6 >= 0) & (d5 <= d6)).unsqueeze(-1), c, point)
    return point


def closest_on_segments(p1, q1, p2, q2) -> tuple[torch.Tensor, torch.Tensor]:
    """Closest points ``(c1, c2)`` of the segments ``p1q1`` and ``p2q2`` (broadcast ``(..., 3)``);
    a segment may be a point (``p = q``)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = (d1 * d1).sum(-1), (d2 * d2).sum(-1)
    b, c, f = (d1 * d2).sum(-1), (d1 * r).sum(-1), (d2 * r).sum(-1)
    denominator = a * e - b * b
    # the parameter on the first segment where the lines are closest (any, when parallel)
    s = torch.where(
        denominator > TINY * (a * e + TINY), (b * f - c * e) / denominator.clamp_min(TINY), 0.0
    )
    s = torch.where(a > TINY, s, 0.0).clamp(0.0, 1.0)
    t = torch.where(e > TINY, (b * s + f) / e.clamp_min(TINY), 0.0)
    # t clamped: then s is recomputed for that end of the second segment
    t_clamped = t.clamp(0.0, 1.0)
    s = torch.where(
        (t != t_clamped) & (a > TINY), ((b * t_clamped - c) / a.clamp_min(TINY)).clamp(0.0, 1.0), s
    )
    return p1 + d1 * s.unsqueeze(-1), p2 + d2 * t_clamped.unsqueeze(-1)


def _unit(x: torch.Tensor) -> torch.Tensor:
    return x / safe_norm(x).unsqueeze(-1)


class Core:
    """A batch of convex cores in the world frame, one per pair (a shape's core without its
    radius); every tensor's leading dimensions are ``(..., P)``, P the pairs.

    Attributes:
        vertices: ``(..., P, V, 3)`` [m].
        corners: ``(..., P, T, 3, 3)`` the surface triangles' corners, None for a point or a
            segment (no surface of its own).
        normals, offsets: ``(..., P, T, 3)``, ``(..., P, T)`` outward face planes ``n·x = d``.
        edges: ``(..., P, E, 2, 3)`` edge end points, None for a point.
        directions: ``(..., P, D, 3)`` the unit directions of its edges (a polytope's between
            faces that are not coplanar), each once; None for a point.
        edge_normals: ``(..., P, E, 2, 3)`` a polytope's outward normals of the two faces
            beside each edge; None for the others.
    """

    def __init__(
        self,
        vertices,
        corners=None,
        normals=None,
        offsets=None,
        edges=None,
        directions=None,
        edge_normals=None,
    ):
        self.vertices, self.corners, self.edges = vertices, corners, edges
        self.directions, self.edge_normals = directions, edge_normals
        self.normals, self.offsets = normals, offsets

    @property
    def solid(self) -> bool:
        """Whether it has a surface (a polytope), so points can lie inside it."""
        return self.corners is not None


def _heights(points: torch.Tensor, solid: Core) -> torch.Tensor:
    """``(..., P, N, T)`` heights of ``points (..., P, N, 3)`` over ``solid``'s face planes."""
    return (points.unsqueeze(-2) * solid.normals.unsqueeze(-3)).sum(-1) - solid.offsets.unsqueeze(
        -2
    )


def _to_surface(points: torch.Tensor, solid: Core, smoothing):
    """Per point of ``points (..., P, N, 3)``: its unsigned distance to ``solid``'s surface
    triangles ``(..., P, N)`` and the nearest surface point ``(..., P, N, 3)``."""
    corners = solid.corners.unsqueeze(-4)  # (..., P, 1, T, 3, 3)
    nearest = closest_on_triangle(
        points.unsqueeze(-2), corners[..., 0, :], corners[..., 1, :], corners[..., 2, :]
    )
    gaps = safe_norm(points.unsqueeze(-2) - nearest)  # (..., P, N, T)
    gap, weights = select(gaps, -1, smoothing)
    return gap, pick(weights, nearest, -1)


def points_to_solid(points: torch.Tensor, solid: Core, smoothing=None):
    """Signed distance of each of ``points (..., P, N, 3)`` to ``solid`` (negative inside).

    Returns ``(distance (..., P, N), surface (..., P, N, 3), normal (..., P, N, 3))``: the
    nearest surface point and the outward unit normal there.
    """
    return _point_terms(points, solid, smoothing)[:3]


def _point_terms(points: torch.Tensor, solid: Core, smoothing):
    """:func:`points_to_solid`'s values, then the heights over every face plane
    ``(..., P, N, T)``, the unsigned distance to the surface and the nearest surface point."""
    heights = _heights(points, solid)
    inside, face_weights = select(heights, -1, smoothing, largest=True)
    face_normal = pick(face_weights, solid.normals.unsqueeze(-3).expand(*heights.shape, 3), -1)
    gap, surface_out = _to_surface(points, solid, smoothing)
    away = points - surface_out
    length = safe_norm(away)
    normal_out = torch.where(
        (length > 1e-9).unsqueeze(-1), away / length.unsqueeze(-1), face_normal
    )
    outside = inside > 0
    distance = torch.where(outside, gap, inside)
    surface = torch.where(
        outside.unsqueeze(-1), surface_out, points - inside.unsqueeze(-1) * face_normal
    )
    normal = torch.where(outside.unsqueeze(-1), normal_out, face_normal)
    return distance, surface, _unit(normal), heights, gap, surface_out


class Separation:
    """The signed distance of two cores with its witnesses, per pair ``(..., P)``.

    Attributes:
        distance: ``(..., P)`` [m], negative when the cores overlap.
        point_a, point_b: ``(..., P, 3)`` witness points on core a and core b [m].
        normal: ``(..., P, 3)`` unit normal from a towards b.
        vertices_a: where b is solid, each of a's vertices against b, as
            :func:`points_to_solid` returns it (distance, surface point, b's outward normal);
            else None. vertices_b: b's vertices against a, likewise.
        crossings: where both are solid, a's witnesses of the closest edge pairs
            ``(..., P, k, 3)`` (see :func:`_edge_pairs`); else None.
    """

    def __init__(
        self, distance, point_a, point_b, normal, vertices_a=None, vertices_b=None, crossings=None
    ):
        self.distance, self.point_a, self.point_b, self.normal = distance, point_a, point_b, normal
        self.vertices_a, self.vertices_b, self.crossings = vertices_a, vertices_b, crossings


def core_separation(a: Core, b: Core, smoothing=None) -> Separation:
    """Signed distance of cores ``a`` and ``b`` pair by pair (see the module's docstring)."""
    gaps, from_a, from_b = [], [], []
    faces = []  # penetration candidates: (depth along a face normal, point a, point b, normal)
    vertices_a = vertices_b = None
    if b.solid:
        terms = _point_terms(a.vertices, b, smoothing)
        vertices_a, (heights, gap, surface) = terms[:3], terms[3:]
        gaps.append(gap)
        from_a.append(a.vertices)
        from_b.append(surface)
        faces.append(_face_axis(heights, a.vertices, b.normals, smoothing, flip=True))
    if a.solid:
        terms = _point_terms(b.vertices, a, smoothing)
        vertices_b, (heights, gap, surface) = terms[:3], terms[3:]
        gaps.append(gap)
        from_a.append(surface)
        from_b.append(b.vertices)
        faces.append(_face_axis(heights, b.vertices, a.normals, smoothing, flip=False))
    edge = None
    lines = a.directions is not None and b.directions is not None
    if lines or not faces:
        edge = _edge_pairs(a.edges, b.edges, smoothing)
        closest = edge[4:]
        gaps.append(edge[0].unsqueeze(-1))
        from_a.append(edge[1].unsqueeze(-2))
        from_b.append(edge[2].unsqueeze(-2))
    gap, weights = select(torch.cat(gaps, -1), -1, smoothing)
    point_a = pick(weights, torch.cat(from_a, -2), -1)
    point_b = pick(weights, torch.cat(from_b, -2), -1)
    if not faces:  # neither core has a volume: cores never overlap
        return Separation(gap, point_a, point_b, _unit(point_b - point_a))
    if lines:  # with faces, one core is a polytope: it has edge normals
        faces.append(_minkowski_edge_axes(a, b, *closest, smoothing))
    # the separating axis theorem: the cores overlap iff no candidate axis separates them,
    # and then the best axis's overlap is the penetration depth
    depth, weights = select(torch.stack([f[0] for f in faces], -1), -1, smoothing, largest=True)
    deep_a = pick(weights, torch.stack([f[1] for f in faces], -2), -1)
    deep_b = pick(weights, torch.stack([f[2] for f in faces], -2), -1)
    deep_normal = _unit(pick(weights, torch.stack([f[3] for f in faces], -2), -1))
    away = point_b - point_a
    length = safe_norm(away)
    apart_normal = torch.where(
        (length > 1e-9).unsqueeze(-1), away / length.unsqueeze(-1), deep_normal
    )
    overlap = depth < 0
    o = overlap.unsqueeze(-1)
    return Separation(
        torch.where(overlap, depth, gap),
        torch.where(o, deep_a, point_a),
        torch.where(o, deep_b, point_b),
        torch.where(o, deep_normal, apart_normal),
        vertices_a,
        vertices_b,
        edge[3] if a.solid and b.solid else None,
    )


def _face_axis(heights, points, normals, smoothing, flip: bool):
    """The best separating face of a solid against ``points``: its separation (the lowest
    point's height, maximized over faces), the witnesses and the normal from core a to b.

    ``heights (..., P, N, T)`` of ``points (..., P, N, 3)`` over the solid's faces with
    ``normals (..., P, T, 3)``; ``flip``: the points are core a's (the normal is reversed)."""
    lowest, point_weights = select(heights, -2, smoothing)  # (..., P, T)
    separation, face_weights = select(lowest, -1, smoothing, largest=True)
    # the lowest point of the chosen face, and its foot on that face's plane
    weights = face_weights.unsqueeze(-2) * point_weights  # (..., P, N, T)
    point = pick(weights.sum(-1), points, -1)
    normal = pick(face_weights, normals, -1)
    foot = point - separation.unsqueeze(-1) * normal
    if flip:
        return separation, point, foot, -normal
    return separation, foot, point, normal


def _edge_pairs(edges_a, edges_b, smoothing):
    """The closest pair of edges: distance ``(..., P)`` and witnesses ``(..., P, 3)``; then
    the witnesses on a's edges of the :data:`EDGE_POINTS` closest pairs ``(..., P, k, 3)``
    (where two faces rest on each other, the corners of their overlap that are neither's
    vertex: edge crossings)."""
    c1, c2 = closest_on_segments(
        edges_a[..., :, None, 0, :], edges_a[..., :, None, 1, :],
        edges_b[..., None, :, 0, :], edges_b[..., None, :, 1, :],
    )  # fmt: skip
    gaps = safe_norm(c2 - c1).flatten(-2)
    gap, weights = select(gaps, -1, smoothing)
    witnesses = c1.flatten(-3, -2)
    nearest = gaps.topk(min(EDGE_POINTS, gaps.shape[-1]), -1, largest=False).indices
    crossings = witnesses.gather(-2, nearest.unsqueeze(-1).expand(*nearest.shape, 3))
    return (
        gap, pick(weights, witnesses, -1), pick(weights, c2.flatten(-3, -2), -1), crossings,
        c1, c2,
    )  # fmt: skip


def _minkowski_edge_axes(a: Core, b: Core, c1, c2, smoothing):
    """The best separating axis among the cross products of a's and b's edges, one core or
    both polytopes, turned to point from a towards b: a penetration candidate like a face's.
    Only the edge pairs that span a face of their Minkowski difference are axes (on the Gauss
    map, the arcs of a polytope's edges cross each other, or the great circle of the
    directions normal to a segment): the edges themselves then support the axis, so the
    separation is the axis's component of the gap between the edges' points, work ``Ea·Eb``
    rather than ``Ea·Eb·(Va + Vb)``.

    ``c1, c2 (..., P, Ea, Eb, 3)``: the closest points of every edge pair, the witnesses."""
    start_a, start_b = a.edges[..., :, None, 0, :], b.edges[..., None, :, 0, :]
    along_a = a.edges[..., :, None, 1, :] - start_a  # (..., P, Ea, 1, 3)
    along_b = b.edges[..., None, :, 1, :] - start_b  # (..., P, 1, Eb, 3)
    if a.edge_normals is not None and b.edge_normals is not None:
        n1, n2 = a.edge_normals[..., :, None, 0, :], a.edge_normals[..., :, None, 1, :]
        m1, m2 = -b.edge_normals[..., None, :, 0, :], -b.edge_normals[..., None, :, 1, :]
        arc_a, arc_b = torch.linalg.cross(n2, n1), torch.linalg.cross(m2, m1)
        cba, dba = (m1 * arc_a).sum(-1), (m2 * arc_a).sum(-1)
        adc, bdc = (n1 * arc_b).sum(-1), (n2 * arc_b).sum(-1)
        face = (cba * dba < 0) & (adc * bdc < 0) & (cba * bdc > 0)
    elif a.edge_normals is not None:  # b a segment
        n1, n2 = a.edge_normals[..., :, None, 0, :], a.edge_normals[..., :, None, 1, :]
        face = (n1 * along_b).sum(-1) * (n2 * along_b).sum(-1) < 0
    else:  # a a segment
        m1, m2 = b.edge_normals[..., None, :, 0, :], b.edge_normals[..., None, :, 1, :]
        face = (m1 * along_a).sum(-1) * (m2 * along_a).sum(-1) < 0
    cross = torch.linalg.cross(along_a.expand_as(c1), along_b.expand_as(c1))
    length = safe_norm(cross)
    axis = cross / length.unsqueeze(-1)
    # from a to b: out of the polytope a through its edge, else into the polytope b
    if a.edge_normals is not None:
        side = (axis * (start_a - a.vertices.mean(-2)[..., None, None, :])).sum(-1)
    else:
        side = (axis * (b.vertices.mean(-2)[..., None, None, :] - start_b)).sum(-1)
    axis = axis * torch.where(side < 0, -1.0, 1.0).unsqueeze(-1)
    gap = (axis * (start_b - start_a)).sum(-1)
    separation = torch.where(face & (length > 1e-9), gap, -1e3).flatten(-2)
    best, weights = select(separation, -1, smoothing, largest=True)
    return (
        best,
        pick(weights, c1.flatten(-3, -2), -1),
        pick(weights, c2.flatten(-3, -2), -1),
        pick(weights, axis.flatten(-3, -2), -1),
    )
