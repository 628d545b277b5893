"""Procedural solid textures (evaluated at 3D object coordinates) and Lambert shading, in numpy."""

from __future__ import annotations

import numpy as np

from holousd.synth._catalog import Texture

__all__ = ["albedo", "shade"]

_LIGHTS = (
    (np.array([0.35, -0.45, 0.82]), 0.5),
    (np.array([-0.6, 0.5, 0.45]), 0.22),
    (np.array([0.1, 0.9, -0.3]), 0.08),
)
_AMBIENT = 0.32


def _hash(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic integer lattice hash -> [0, 1)."""
    h = (ix.astype(np.int64) * 73856093) ^ (iy.astype(np.int64) * 19349663) ^ (iz.astype(np.int64) * 83492791)
    h = (h ^ (seed * 2654435761)) & 0xFFFFFFFF
    h = ((h >> 16) ^ h) * 0x45D9F3B & 0xFFFFFFFF
    h = ((h >> 16) ^ h) * 0x45D9F3B & 0xFFFFFFFF
    h = (h >> 16) ^ h
    return (h & 0xFFFFFF).astype(np.float64) / float(0x1000000)


def _noise(p: np.ndarray, seed: int) -> np.ndarray:
    """Trilinear value noise of [N, 3] points (unit lattice) -> [N] in [0, 1)."""
    base = np.floor(p)
    f = p - base
    f = f * f * (3 - 2 * f)
    i = base.astype(np.int64)
    out = np.zeros(len(p))
    for dx in (0, 1):
        wx = f[:, 0] if dx else 1 - f[:, 0]
        for dy in (0, 1):
            wy = f[:, 1] if dy else 1 - f[:, 1]
            for dz in (0, 1):
                wz = f[:, 2] if dz else 1 - f[:, 2]
                out += wx * wy * wz * _hash(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, seed)
    return out


def _fbm(p: np.ndarray, seed: int, octaves: int = 3) -> np.ndarray:
    total, amp, norm = np.zeros(len(p)), 1.0, 0.0
    for o in range(octaves):
        total += amp * _noise(p * (2.0**o), seed + 101 * o)
        norm += amp
        amp *= 0.5
    return total / norm


def albedo(points: np.ndarray, normals: np.ndarray, texture: Texture) -> np.ndarray:
    """[N, 3] albedo of ``texture`` at [N, 3] object-coordinate ``points`` (``normals`` [N, 3] object frame)."""
    c1, c2 = np.asarray(texture.color), np.asarray(texture.color2)
    s, seed = texture.scale, texture.seed
    q = points / s
    kind = texture.pattern
    if kind == "wood":
        warp = 1.5 * _fbm(q * np.array([0.15, 1.0, 1.0]), seed)
        t = 0.5 + 0.5 * np.sin(2 * np.pi * (q[:, 1] + 0.3 * q[:, 2] + warp))
        t = t**3 * 0.8 + 0.2 * _noise(q * np.array([0.05, 3.0, 3.0]), seed + 7)
    elif kind == "checker":
        t = (np.floor(q[:, 0] + 1e-4) + np.floor(q[:, 1] + 1e-4) + np.floor(q[:, 2] + 1e-4)) % 2
        t = 0.85 * t + 0.15 * _fbm(q * 2.0, seed)
    elif kind == "stripes":
        t = (np.floor(q[:, 0] + 0.5 * q[:, 2]) % 3 == 0).astype(np.float64) * 0.8 + 0.2 * _fbm(q * 3, seed)
    elif kind == "tiles":
        cell = np.floor(q[:, :2])
        frac = q[:, :2] - cell
        grout = np.minimum(frac, 1 - frac).min(axis=1) < 0.03
        tint = _hash(cell[:, 0].astype(np.int64), cell[:, 1].astype(np.int64), np.zeros(len(q), np.int64), seed)
        t = np.where(grout, 1.0, 0.25 * tint + 0.15 * _fbm(q * 4, seed + 3))
    elif kind == "fabric":
        weave = 0.5 + 0.25 * (np.sin(2 * np.pi * q[:, 0]) + np.sin(2 * np.pi * (q[:, 1] + q[:, 2])))
        t = 0.4 * weave + 0.6 * _fbm(q * 0.15, seed)
    elif kind == "plaster":
        t = _fbm(q, seed, octaves=4)
        t = np.clip((t - 0.3) * 1.6, 0, 1)
    else:  # "noise"
        t = _fbm(q, seed)
        t = np.clip((t - 0.25) * 2.0, 0, 1)
    t = np.clip(t, 0, 1)[:, None]
    return c1 * (1 - t) + c2 * t


def shade(colour: np.ndarray, normals_world: np.ndarray) -> np.ndarray:
    """Lambert shading of [N, 3] albedo with fixed directional lights; [N, 3] world normals -> [N, 3] in [0, 1]."""
    light = np.full(len(colour), _AMBIENT)
    for direction, strength in _LIGHTS:
        d = direction / np.linalg.norm(direction)
        light += strength * np.clip(normals_world @ d, 0, None)
    return np.clip(colour * light[:, None], 0, 1)
