"""The motion app's scene (`fxspace.studio.serve_motion`): the ground, the walker's body
made once and updated in place each frame (`_Body`: limbs as instances of one unit
cylinder, joint spheres, foot contacts, the skinned character when it wears one), the
samples' panel image and the following camera.
"""

from __future__ import annotations

import numpy as np

from fxspace.studio._server import density_rgba, frame_density

__all__ = ["body_mesh", "bone_instances", "samples_image"]


def _bones(parents) -> tuple[np.ndarray, np.ndarray]:
    j = np.asarray([k for k, p in enumerate(parents) if p >= 0])
    return np.asarray(parents)[j], j


def body_mesh(X: np.ndarray, parents, radius: float = 0.045, sides: int = 10):
    """Shaded limbs: one cylinder per bone (``sides`` facets, radius ``radius``) from the
    world joint positions ``X`` ``(J, 3)``; joints get spheres separately (`_SPHERE`).
    Returns ``(vertices (V, 3) float32, faces (F, 3) uint32)``."""
    pi, ji = _bones(parents)
    a, b = X[pi], X[ji]
    d = b - a
    L = np.linalg.norm(d, axis=1)
    keep = L > 1e-4
    a, b, d, L = a[keep], b[keep], d[keep], L[keep]
    u = d / L[:, None]
    h = np.where(np.abs(u[:, 1:2]) < 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(u, h)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(u, e1)
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = radius * (
        np.cos(ang)[None, :, None] * e1[:, None] + np.sin(ang)[None, :, None] * e2[:, None]
    )
    V = np.concatenate([a[:, None] + ring, b[:, None] + ring], axis=1)  # (B, 2·sides, 3)
    k = np.arange(sides)
    k1 = (k + 1) % sides
    quad = np.concatenate(
        [np.stack([k, k1, sides + k], 1), np.stack([k1, sides + k1, sides + k], 1)]
    )
    F = quad[None] + (2 * sides * np.arange(len(a)))[:, None, None]
    return V.reshape(-1, 3).astype(np.float32), F.reshape(-1, 3).astype(np.uint32)


def _sphere(n_lat: int = 6, n_lon: int = 10):
    th = np.linspace(0, np.pi, n_lat + 1)
    ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    v = np.stack([np.sin(th)[:, None] * np.cos(ph), np.cos(th)[:, None] * np.ones_like(ph),
                  np.sin(th)[:, None] * np.sin(ph)], -1).reshape(-1, 3)  # fmt: skip
    f = []
    for i in range(n_lat):
        for j in range(n_lon):
            a, b = i * n_lon + j, i * n_lon + (j + 1) % n_lon
            f += [[a, a + n_lon, b], [b, a + n_lon, b + n_lon]]
    return v.astype(np.float32), np.asarray(f, np.uint32)


_SPHERE = _sphere()


def samples_image(P: np.ndarray, current: np.ndarray, size: int = 160) -> np.ndarray:
    """The sample cloud ``P`` ``(S, 2)`` of a parameter space as an RGBA image, the
    current parameter marked in red (the separate panel of the app)."""
    dens = frame_density(np.concatenate([P, current[None]]), size)
    img = density_rgba(dens.counts[::-1], (60, 60, 140))
    img[..., 3] = np.maximum(img[..., 3], 30)
    c = np.clip(((current - dens.lo) / (dens.hi - dens.lo) * size).astype(int), 2, size - 3)
    img[size - 1 - c[1] - 2 : size - c[1] + 2, c[0] - 2 : c[0] + 3] = (220, 40, 40, 255)
    return img


def _follow_camera(server, target: np.ndarray) -> None:
    for client in server.get_clients().values():
        cam = client.camera
        off = np.asarray(cam.position) - np.asarray(cam.look_at)
        with client.atomic():
            cam.look_at = tuple(target)
            cam.position = tuple(target + off)


def _scene(server):
    """Ground plane, grid, light; Y up."""
    server.scene.set_up_direction("+y")
    g = 30.0
    ground = server.scene.add_mesh_simple(
        "/ground/plane", np.asarray([[-g, -0.002, -g], [g, -0.002, -g], [g, -0.002, g],
                                     [-g, -0.002, g]], np.float32),
        np.asarray([[0, 2, 1], [0, 3, 2]], np.uint32), color=(205, 200, 185),
        side="double", receive_shadow=True,
    )  # fmt: skip
    grid = server.scene.add_grid("/ground/grid", width=2 * g, height=2 * g, plane="xz",
                                 cell_size=1.0)  # fmt: skip
    return ground, grid


def bone_instances(X: np.ndarray, parents, radius: float = 0.045):
    """The limbs as instances of one unit cylinder (radius 1, from z = 0 to z = 1), one per
    bone: ``(wxyzs (B, 4), positions (B, 3), scales (B, 3))`` float32, the rotation taking
    +z to the bone, the position at the parent joint, the scale ``(r, r, length)``.

    What the app sends per frame instead of a new mesh (`body_mesh`): three small arrays
    that viser updates in place, so a software-rendered page keeps up."""
    pi, ji = _bones(parents)
    a = np.asarray(X, np.float64)[pi]
    d = np.asarray(X, np.float64)[ji] - a
    L = np.linalg.norm(d, axis=1)
    u = d / np.maximum(L, 1e-12)[:, None]
    # shortest-arc quaternion from +z to u: (1 + u_z, −u_y, u_x, 0), normalised
    q = np.stack([1.0 + u[:, 2], -u[:, 1], u[:, 0], np.zeros_like(L)], axis=1)
    flip = q[:, 0] < 1e-9  # u ≈ −z (or a zero-length bone pointing nowhere): 180° about x
    q[flip] = (0.0, 1.0, 0.0, 0.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    scales = np.stack([np.full_like(L, radius), np.full_like(L, radius), L], axis=1)
    return q.astype(np.float32), a.astype(np.float32), scales.astype(np.float32)


def _unit_cylinder(sides: int = 10) -> tuple[np.ndarray, np.ndarray]:
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = np.stack([np.cos(ang), np.sin(ang), np.zeros(sides)], 1)
    V = np.concatenate([ring, ring + [0.0, 0.0, 1.0]]).astype(np.float32)
    k = np.arange(sides)
    k1 = (k + 1) % sides
    F = np.concatenate([np.stack([k, k1, sides + k], 1), np.stack([k1, sides + k1, sides + k], 1)])
    return V, F.astype(np.uint32)


class _Body:
    """The character's scene nodes, made once and then updated in place (only the changed
    arrays travel to the page each frame)."""

    def __init__(self, server, ctl, character=None):
        self.server, self.ctl = server, ctl
        X = ctl.joints()
        self.character, self.skin, self.center = character, None, None
        if character is not None:  # the skinned character: LBS of its IK pose each frame
            _, v = character.step(X)
            self.skin = server.scene.add_mesh_simple(
                "/character/skin", v.astype(np.float32),
                np.asarray(character.mesh.faces, np.uint32), color=(200, 170, 140),
            )  # fmt: skip
            self.center = v.mean(0)
        q, p, s = bone_instances(X, ctl.skel.parents)
        cyl = _unit_cylinder()
        sc = server.scene
        self.limbs = sc.add_batched_meshes_simple(
            "/character/limbs", cyl[0], cyl[1], batched_wxyzs=q, batched_positions=p,
            batched_scales=s, batched_colors=(70, 110, 170), lod="off",
        )  # fmt: skip
        self.joints = sc.add_batched_meshes_simple(
            "/character/joints", _SPHERE[0] * 0.05, _SPHERE[1],
            batched_wxyzs=np.tile(np.float32([1, 0, 0, 0]), (len(X), 1)),
            batched_positions=X.astype(np.float32), batched_colors=(90, 130, 190), lod="off",
        )  # fmt: skip
        feet, cols = self._feet(X)
        self.contacts = sc.add_batched_meshes_simple(
            "/ground/contacts", _SPHERE[0] * np.asarray([0.09, 0.004, 0.09], np.float32),
            _SPHERE[1], batched_wxyzs=np.tile(np.float32([1, 0, 0, 0]), (len(feet), 1)),
            batched_positions=feet, batched_colors=cols, lod="off",
        )  # fmt: skip
        self.samples = None

    def _feet(self, X):
        feet = X[list(self.ctl.setup.feet)].astype(np.float32) * np.float32([1, 0, 1])
        on = [(40, 200, 60) if c else (150, 150, 150) for c in self.ctl.contacts()]
        return feet, np.asarray(on, np.uint8)

    def show_capsules(self, on: bool) -> None:
        """The capsule body (limbs and joints) on or off; the skinned character the other
        way round."""
        self.limbs.visible = self.joints.visible = bool(on)
        if self.skin is not None:
            self.skin.visible = not on

    def draw(self, show_samples: bool) -> None:
        X = self.ctl.joints()
        q, p, s = bone_instances(X, self.ctl.skel.parents)
        feet, cols = self._feet(X)
        v = None
        if self.skin is not None and self.skin.visible:
            _, v = self.character.step(X)
            self.center = v.mean(0)
        with self.server.atomic():
            if v is not None:
                self.skin.vertices = v.astype(np.float32)
            self.limbs.batched_wxyzs, self.limbs.batched_positions = q, p
            self.limbs.batched_scales = s
            self.joints.batched_positions = X.astype(np.float32)
            self.contacts.batched_positions, self.contacts.batched_colors = feet, cols
            up = self.ctl.upper_samples_world() if show_samples else None
            if up is not None and self.samples is None:
                self.samples = self.server.scene.add_point_cloud(
                    "/samples/upper", up.astype(np.float32), (60, 170, 60), point_size=0.015
                )
            elif up is not None:
                self.samples.points = up.astype(np.float32)
            if self.samples is not None:
                self.samples.visible = up is not None
