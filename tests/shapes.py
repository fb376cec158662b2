"""Synthetic cages that stress a solver: boxes, perturbed and stretched icospheres, random star-shaped cages, thin
slabs, two lobes joined by a thin neck and tori, each with points inside it to sample weights at.

Real cages are few; these are many, made in code, deterministic for a seed, and closed, outward oriented and free
of self-intersections by construction (a star-shaped cage displaces an icosphere's vertices along their rays, so
no triangle turns over; the others are boxes, surfaces of revolution and tori). Every cage is rotated so that
the grid's axes meet it at no special angle, except where ``rotation`` says otherwise (axis-aligned boxes put grid
nodes on faces, another case worth sweeping). The points are the cage's surface points moved towards a skeleton
inside it (the centre, or the axis of a surface of revolution): inside by construction.

:func:`stress_pairs` is the family the convergence sweeps use (``tests/test_convergence_sweep.py`` on the CPU,
``benchmarks/bench_convergence.py`` on a GPU).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

__all__ = ["SyntheticPair", "random_rotation", "box_pair", "ellipsoid_pair", "star_pair", "slab_pair",
           "dumbbell_pair", "torus_pair", "stress_pairs", "latitude_longitude_sphere"]

#: how far towards the skeleton the sample points are moved (1: on the cage, 0: on the skeleton)
POINT_LEVELS = (0.95, 0.8, 0.5, 0.2)


@dataclass(frozen=True)
class SyntheticPair:
    """A cage and points inside it.

    Attributes
    ----------
    name : str, what the pair is (kind and parameters)
    cage_vertices : (L, 3) float64
    cage_faces : (T, 3) int64, outward oriented
    points : (V, 3) float64, strictly inside the cage

    The cage and the points are what :func:`warp_stokes.bind` takes: ``bind((pair.points, []), pair.cage)``.
    """

    name: str
    cage_vertices: np.ndarray
    cage_faces: np.ndarray
    points: np.ndarray

    @property
    def cage(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices, faces) of the cage."""
        return self.cage_vertices, self.cage_faces

    @property
    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """The points as a mesh without faces."""
        return self.points, np.zeros((0, 3), dtype=np.int64)


def random_rotation(seed: int) -> np.ndarray:
    """A rotation matrix drawn uniformly for ``seed`` (QR of a Gaussian matrix, signs fixed, determinant 1).

    Examples
    --------
    >>> r = random_rotation(0)
    >>> bool(np.allclose(r @ r.T, np.eye(3))), round(float(np.linalg.det(r)), 6)
    (True, 1.0)
    """
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def _pair(name, vertices, faces, points, rotation) -> SyntheticPair:
    rotation = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    return SyntheticPair(name, np.asarray(vertices, np.float64) @ rotation.T, np.asarray(faces, np.int64),
                         np.asarray(points, np.float64) @ rotation.T)


def _surface_samples(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The cage's vertices, edge midpoints and face centroids."""
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    return np.concatenate([vertices, vertices[edges].mean(axis=1), vertices[faces].mean(axis=1)])


def _towards(samples: np.ndarray, skeleton: np.ndarray) -> np.ndarray:
    """``samples`` moved towards their ``skeleton`` points by each of POINT_LEVELS."""
    return np.concatenate([skeleton + t * (samples - skeleton) for t in POINT_LEVELS])


def _star_points(vertices, faces, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    samples = _surface_samples(vertices, faces)
    return _towards(samples, np.broadcast_to(np.asarray(centre, np.float64), samples.shape))


def box_pair(extents=(1.0, 1.0, 1.0), rotation=None) -> SyntheticPair:
    """A box cage (8 handles, 12 triangles) centred at the origin.

    Parameters
    ----------
    extents : (3,) side lengths
    rotation : (3, 3) or None, applied to cage and points (None: axis-aligned, grid nodes then lie on its faces)

    Returns
    -------
    SyntheticPair

    Examples
    --------
    >>> pair = box_pair((2.0, 1.0, 0.5))
    >>> pair.cage_vertices.shape, pair.cage_faces.shape
    ((8, 3), (12, 3))
    """
    half = 0.5 * np.asarray(extents, dtype=np.float64)
    corners = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], np.float64) * half
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    name = "box " + "x".join(f"{e:g}" for e in extents) + ("" if rotation is None else " rotated")
    return _pair(name, corners, faces, _star_points(corners, faces), rotation)


@functools.lru_cache(maxsize=None)
def _icosphere_made(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(sphere.vertices, np.float64), np.asarray(sphere.faces, np.int64)


def _icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of trimesh's icosphere, copies of one made once per count (trimesh takes tens of ms each
    time, and the family asks for the same few dozens of times)."""
    vertices, faces = _icosphere_made(subdivisions)
    return vertices.copy(), faces.copy()


def ellipsoid_pair(radii=(1.0, 1.0, 1.0), noise: float = 0.0, subdivisions: int = 2, seed: int = 0,
                   rotation=None) -> SyntheticPair:
    """An icosphere (42, 162, 642 handles for 1, 2, 3 subdivisions) with every vertex's radius scaled by a random
    factor in [1 - noise, 1 + noise], then stretched to ``radii``.

    Examples
    --------
    >>> pair = ellipsoid_pair((1.0, 0.5, 0.25), noise=0.2, subdivisions=1, seed=3)
    >>> len(pair.cage_vertices), bool(np.abs(pair.cage_vertices).max() <= 1.2)
    (42, True)
    """
    if not 0.0 <= noise < 1.0:
        raise ValueError(f"noise must be in [0, 1), got {noise}")
    vertices, faces = _icosphere(subdivisions)
    scale = 1.0 + noise * np.random.default_rng(seed).uniform(-1.0, 1.0, size=len(vertices))
    stretch = np.asarray(radii, np.float64)
    vertices = vertices * scale[:, None] * stretch
    name = (f"ellipsoid {'x'.join(f'{r:g}' for r in radii)} noise {noise:g} ({len(vertices)} handles, seed {seed})")
    return _pair(name, vertices, faces, _star_points(vertices, faces), rotation)


def star_pair(seed: int, subdivisions: int = 2, bumps: int = 8, amplitude: float = 0.6,
              rotation="random") -> SyntheticPair:
    """A random star-shaped cage: an icosphere's vertices at radius ``1 + sum of bumps`` along their rays (Gaussian
    bumps of random sign, centre and width on the sphere, their heights' absolute values summing to ``amplitude``
    times the square root of ``bumps``, the radius kept at 0.25 or more), so arms, dents and necks of every size
    appear.

    Examples
    --------
    >>> pair = star_pair(7, subdivisions=1)
    >>> len(pair.cage_vertices), len(pair.points) > 100
    (42, True)
    """
    rng = np.random.default_rng(seed)
    vertices, faces = _icosphere(subdivisions)
    centres = rng.normal(size=(bumps, 3))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    widths = rng.uniform(0.15, 0.8, size=bumps)
    heights = rng.uniform(-1.0, 1.0, size=bumps)
    heights *= amplitude / max(np.abs(heights).sum(), 1e-12) * bumps ** 0.5
    radius = 1.0 + (heights * np.exp(-(1.0 - vertices @ centres.T) / widths)).sum(axis=1)
    vertices = vertices * np.maximum(radius, 0.25)[:, None]
    rotation = random_rotation(seed) if isinstance(rotation, str) and rotation == "random" else rotation
    return _pair(f"star seed {seed} ({len(vertices)} handles)", vertices, faces, _star_points(vertices, faces),
                 rotation)


def slab_pair(thickness: float = 0.1, aspect: float = 1.0, rotation="random", seed: int = 0) -> SyntheticPair:
    """A thin slab: a box 1 x ``aspect`` x ``thickness``, in-plane faces split into a 4 x 4 grid of quads (50
    handles), so handles lie across it and not only at its corners.

    Examples
    --------
    >>> pair = slab_pair(0.05)
    >>> len(pair.cage_vertices), bool(np.ptp(pair.points @ random_rotation(0), axis=0)[2] < 0.05)
    (50, True)
    """
    k = 4
    u = np.linspace(-0.5, 0.5, k + 1)
    grid = np.array([(x, y * aspect) for y in u for x in u])
    ids = np.arange((k + 1) ** 2).reshape(k + 1, k + 1)
    bottom = np.column_stack([grid, np.full(len(grid), -0.5 * thickness)])
    top = np.column_stack([grid, np.full(len(grid), 0.5 * thickness)])
    vertices = np.concatenate([bottom, top])
    top_ids = ids + len(grid)
    faces = []
    for i in range(k):
        for j in range(k):
            a, b, c, d = ids[i, j], ids[i, j + 1], ids[i + 1, j + 1], ids[i + 1, j]
            faces += [(a, c, b), (a, d, c)]  # bottom, facing -z
            a, b, c, d = top_ids[i, j], top_ids[i, j + 1], top_ids[i + 1, j + 1], top_ids[i + 1, j]
            faces += [(a, b, c), (a, c, d)]  # top, facing +z
    rim = list(ids[0, :]) + list(ids[1:, -1]) + list(ids[-1, -2::-1]) + list(ids[-2:0:-1, 0])
    for p, q in zip(rim, rim[1:] + rim[:1]):  # the rim, walked counter-clockwise seen from +z
        faces += [(p, q, q + len(grid)), (p, q + len(grid), p + len(grid))]
    faces = np.array(faces)
    rotation = random_rotation(seed) if isinstance(rotation, str) and rotation == "random" else rotation
    return _pair(f"slab 1x{aspect:g}x{thickness:g}", vertices, faces, _star_points(vertices, faces), rotation)


def latitude_longitude_sphere(rings: int, sections: int, radius: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A sphere of ``rings`` bands from pole to pole and ``sections`` around (2 + (rings - 1) sections vertices),
    each quad split along one diagonal, outward: a cage of thousands of handles with slivers at the poles.

    Examples
    --------
    >>> vertices, faces = latitude_longitude_sphere(49, 102)
    >>> len(vertices), len(faces)
    (4898, 9792)
    """
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2 * np.pi, sections, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    band = np.column_stack([np.sin(t.ravel()) * np.cos(p.ravel()), np.sin(t.ravel()) * np.sin(p.ravel()),
                            np.cos(t.ravel())])
    vertices = radius * np.vstack([[0, 0, 1], band, [0, 0, -1]])
    ring = lambda i, j: 1 + i * sections + j % sections  # noqa: E731
    faces = [[0, ring(0, j), ring(0, j + 1)] for j in range(sections)]
    for i in range(rings - 2):
        for j in range(sections):
            faces += [[ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)], [ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]]
    faces += [[len(vertices) - 1, ring(rings - 2, j + 1), ring(rings - 2, j)] for j in range(sections)]
    return vertices, np.array(faces, dtype=np.int64)


def _revolved(profile: np.ndarray, sections: int):
    import trimesh

    surface = trimesh.creation.revolve(profile, sections=sections)
    return np.asarray(surface.vertices, np.float64), np.asarray(surface.faces, np.int64)


def dumbbell_pair(neck: float = 0.1, sections: int = 12, rotation="random", seed: int = 0,
                  ball_points: int = 9) -> SyntheticPair:
    """Two balls of radius 0.5 joined by a neck of radius ``neck`` and length 0.6 (a surface of revolution about
    z; ``ball_points`` profile points from pole to pole of each ball, ``sections`` around the axis); the points sit
    between the axis and the surface.

    Examples
    --------
    >>> pair = dumbbell_pair(0.05)
    >>> radial = np.linalg.norm((pair.points @ random_rotation(0))[:, :2], axis=1)
    >>> bool(radial.max() < 0.5)
    True
    """
    if not 0.0 < neck < 0.5:
        raise ValueError(f"the neck's radius must be in (0, 0.5), got {neck}")
    angles = np.linspace(0.0, np.pi, ball_points)
    ball = np.column_stack([0.5 * np.sin(angles), -0.5 * np.cos(angles)])  # from the bottom pole up
    lower = ball + [0.0, -0.8]
    upper = ball + [0.0, 0.8]
    # the neck leaves each ball where the ball's radius equals the neck's
    z_joint = np.sqrt(0.25 - neck**2)
    lower = lower[lower[:, 1] < -0.8 + z_joint - 1e-9]
    upper = upper[upper[:, 1] > 0.8 - z_joint + 1e-9]
    profile = np.concatenate([lower, [[neck, -0.8 + z_joint], [neck, -0.3], [neck, 0.3], [neck, 0.8 - z_joint]],
                              upper])
    vertices, faces = _revolved(profile, sections)
    samples = _surface_samples(vertices, faces)
    axis = np.column_stack([np.zeros((len(samples), 2)), samples[:, 2]])
    points = _towards(samples, axis)
    points = points[np.abs(points[:, 2]) < 1.25]  # not at the poles, where the surface meets the axis
    rotation = random_rotation(seed) if isinstance(rotation, str) and rotation == "random" else rotation
    return _pair(f"dumbbell neck {neck:g}", vertices, faces, points, rotation)


def torus_pair(minor: float = 0.25, major_sections: int = 16, minor_sections: int = 6, rotation="random",
               seed: int = 0) -> SyntheticPair:
    """A torus of major radius 1 and tube radius ``minor`` (a cage with a hole).

    Examples
    --------
    >>> pair = torus_pair(0.2)
    >>> len(pair.cage_vertices)
    96
    """
    import trimesh

    surface = trimesh.creation.torus(1.0, minor, major_sections=major_sections, minor_sections=minor_sections)
    vertices, faces = np.asarray(surface.vertices, np.float64), np.asarray(surface.faces, np.int64)
    samples = _surface_samples(vertices, faces)
    ring = samples.copy()
    ring[:, 2] = 0.0
    ring /= np.linalg.norm(ring, axis=1, keepdims=True)  # the tube's core circle
    rotation = random_rotation(seed) if isinstance(rotation, str) and rotation == "random" else rotation
    return _pair(f"torus minor {minor:g}", vertices, faces, _towards(samples, ring), rotation)


def stress_pairs(seed: int = 0, stars: int = 8, detail: int = 2) -> list[SyntheticPair]:
    """The family of synthetic pairs the convergence sweeps run over: boxes (axis-aligned, rotated, elongated),
    perturbed and stretched icospheres, ``stars`` random star-shaped cages, thin slabs, dumbbells with thin necks
    and tori; deterministic for ``seed``. ``detail`` 2 gives cages of 8-218 handles (icospheres of up to 162); 1 the
    same shapes with fewer handles (62 at most: a sweep on a CPU).

    Examples
    --------
    >>> pairs = stress_pairs()
    >>> len(pairs), len({p.name for p in pairs}) == len(pairs)
    (24, True)
    >>> max(len(p.cage_vertices) for p in stress_pairs(detail=1))
    62
    """
    if detail not in (1, 2):
        raise ValueError(f"detail must be 1 or 2, got {detail}")
    rotation = [random_rotation(seed + k) for k in range(8)]
    sphere = detail  # icosphere subdivisions: 42 or 162 handles
    pairs = [
        box_pair((1.0, 1.0, 1.0)),
        box_pair((1.0, 1.0, 1.0), rotation[1]),
        box_pair((1.0, 0.35, 0.2), rotation[2]),
        ellipsoid_pair(noise=0.15, subdivisions=1, seed=seed, rotation=rotation[3]),
        ellipsoid_pair(noise=0.3, subdivisions=sphere, seed=seed + 1, rotation=rotation[4]),
        ellipsoid_pair((1.0, 0.5, 0.25), noise=0.1, subdivisions=sphere, seed=seed + 2, rotation=rotation[5]),
        ellipsoid_pair((1.0, 0.2, 0.2), noise=0.0, subdivisions=sphere, seed=seed, rotation=rotation[6]),
        ellipsoid_pair((1.0, 1.0, 0.12), noise=0.05, subdivisions=sphere, seed=seed + 3, rotation=rotation[7]),
    ]
    pairs += [star_pair(seed + 100 + k, subdivisions=min(1 + k % 2, sphere)) for k in range(stars)]
    pairs += [slab_pair(t, aspect=a, seed=seed + 10 + k) for k, (t, a) in enumerate([(0.08, 1.0), (0.12, 0.5),
                                                                                         (0.2, 0.3)])]
    pairs += [dumbbell_pair(r, seed=seed + 20 + k, sections=12 if detail == 2 else 6,
                            ball_points=9 if detail == 2 else 5) for k, r in enumerate((0.05, 0.1, 0.2))]
    pairs += [torus_pair(m, seed=seed + 30 + k, major_sections=16 if detail == 2 else 10,
                         minor_sections=6 if detail == 2 else 4) for k, m in enumerate((0.12, 0.3))]
    return pairs
