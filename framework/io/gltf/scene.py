"""The glTF node hierarchy and its animation: node transforms, world matrices, sampled clips."""

from __future__ import annotations

import numpy as np

from rigslim.errors import InputError
from rigslim.io.gltf.document import GltfDocument, expect_accessor_type, read_accessor
from rigslim.io.transforms import slerp, trs_matrix


def node_trs(node: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """A node's rest translation, rotation and scale, or None when it has a ``matrix``."""
    if "matrix" in node:
        return None
    return (np.array(node.get("translation", [0.0, 0.0, 0.0]), float),
            np.array(node.get("rotation", [0.0, 0.0, 0.0, 1.0]), float),
            np.array(node.get("scale", [1.0, 1.0, 1.0]), float))


def node_matrix(node: dict) -> np.ndarray:
    """A node's rest local transform (4 x 4): its column-major ``matrix`` or ``T @ R @ S``."""
    trs = node_trs(node)
    if trs is None:  # the node has a matrix
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
    return trs_matrix(*trs)


def node_parents(doc: dict) -> np.ndarray:
    """(nodes,) parent node index of every node (-1 for roots)."""
    nodes = doc.get("nodes", [])
    parent = np.full(len(nodes), -1, dtype=np.int64)
    for i, node in enumerate(nodes):
        for c in node.get("children", []):
            parent[c] = i
    return parent


def _topological(parent: np.ndarray) -> list[int]:
    """Node indices with every parent before its children (iterative; rejects cycles)."""
    order, seen = [], np.zeros(len(parent), bool)
    for i in range(len(parent)):
        chain = []
        j = i
        while j >= 0 and not seen[j]:
            chain.append(j)
            if len(chain) > len(parent):
                raise InputError("the node hierarchy has a cycle", field="nodes", fix="repair the file")
            j = int(parent[j])
        for j in reversed(chain):
            seen[j] = True
            order.append(j)
    return order


def world_matrices(local: np.ndarray, parent: np.ndarray) -> np.ndarray:
    """Global transforms from local ones.

    Parameters
    ----------
    local : (nodes, ..., 4, 4) array
    parent : (nodes,) int array, -1 for roots

    Returns
    -------
    (nodes, ..., 4, 4) array
        ``G(n) = G(parent(n)) @ L(n)``, ``G(root) = L(root)``.
    """
    world = np.empty_like(local)
    for i in _topological(parent):
        world[i] = local[i] if parent[i] < 0 else world[parent[i]] @ local[i]
    return world


def sample_sampler(times: np.ndarray, values: np.ndarray, interpolation: str, t: np.ndarray,
                   *, rotation: bool = False) -> np.ndarray:
    """Evaluate one animation sampler at times ``t``.

    Parameters
    ----------
    times : (K,) increasing keyframe times
    values : (K, c) keyframe values, or (3K, c) for CUBICSPLINE
        (in-tangent, value, out-tangent per keyframe)
    interpolation : {"LINEAR", "STEP", "CUBICSPLINE"}
    t : (p,) sample times; clamped to the keyframe range
    rotation : bool
        Values are quaternions: LINEAR uses :func:`slerp`, CUBICSPLINE results
        are normalised.

    Returns
    -------
    (p, c) array

    Notes
    -----
    CUBICSPLINE (glTF 2.0 Appendix C) between keys k and k+1, ``d = t_{k+1} - t_k``,
    ``s = (t - t_k) / d``::

        p(s) = (2s^3 - 3s^2 + 1) v_k + (s^3 - 2s^2 + s) d b_k
             + (-2s^3 + 3s^2) v_{k+1} + (s^3 - s^2) d a_{k+1}

    with ``b_k`` the out-tangent of key k and ``a_{k+1}`` the in-tangent of key k+1.
    """
    times = np.asarray(times, float)
    t = np.clip(np.asarray(t, float), times[0], times[-1])
    K = len(times)
    if interpolation == "CUBICSPLINE":
        V = values.reshape(K, 3, -1)
        a, v, b = V[:, 0], V[:, 1], V[:, 2]
    else:
        v = values.reshape(K, -1)
    if K == 1:
        out = np.repeat(v[:1], len(t), axis=0)
        return out / np.linalg.norm(out, axis=-1, keepdims=True) if rotation else out
    k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, K - 2)
    d = times[k + 1] - times[k]
    s = np.where(d > 0, (t - times[k]) / np.where(d > 0, d, 1.0), 0.0)
    if interpolation == "STEP":
        out = np.where((s >= 1.0)[:, None], v[k + 1], v[k])
    elif interpolation == "CUBICSPLINE":
        s2, s3 = s * s, s * s * s
        h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
        out = (h00[:, None] * v[k] + (h10 * d)[:, None] * b[k] + h01[:, None] * v[k + 1]
               + (h11 * d)[:, None] * a[k + 1])
        if rotation:
            out = out / np.linalg.norm(out, axis=-1, keepdims=True)
    elif interpolation == "LINEAR":
        if rotation:
            out = slerp(v[k], v[k + 1], s)
        else:
            out = (1 - s)[:, None] * v[k] + s[:, None] * v[k + 1]
    else:
        raise ValueError(f"unknown interpolation {interpolation!r}")
    return out


def find_animation(doc: GltfDocument, animation) -> int | None:
    """Index of an animation given by name or index (None when the file has none and none is asked)."""
    anims = doc.json.get("animations", [])
    if animation is None:
        return 0 if anims else None
    if isinstance(animation, (int, np.integer)) or (isinstance(animation, str) and animation.isdigit()
                                                    and not any(a.get("name") == animation for a in anims)):
        i = int(animation)
        if 0 <= i < len(anims):
            return i
        raise InputError(f"animation index {i} is out of range (the file has {len(anims)})", source=doc.path,
                         field="animation", fix=f"choose 0..{len(anims) - 1}" if anims else "remove 'animation'")
    names = [a.get("name", f"#{i}") for i, a in enumerate(anims)]
    if animation in names:
        return names.index(animation)
    from rigslim.errors import closest

    raise InputError(f"no animation named '{animation}'", source=doc.path, field="animation",
                     fix=closest(str(animation), names) if names else "the file has no animations")


def animation_duration(doc: GltfDocument, index: int) -> float:
    """Largest keyframe time over the animation's samplers (seconds)."""
    anim = doc.json["animations"][index]
    end = 0.0
    for s in anim.get("samplers", []):
        times = np.asarray(read_accessor(doc, s["input"]), np.float64)
        times = times[np.isfinite(times)]  # sampler_keys refuses the others with their place
        if times.size:
            end = max(end, float(times.max()))
    return end


_PATH_WIDTH = {"translation": 3, "rotation": 4, "scale": 3}


def sampler_keys(doc: GltfDocument, animation: int, index: int, path: str) -> tuple[np.ndarray, np.ndarray]:
    """Key times and values of a sampler driving ``path``, checked.

    Times must be finite, non-negative and strictly increasing (glTF 2.0
    section 3.11); there must be one value per key (three, in-tangent /
    value / out-tangent, for CUBICSPLINE) of the path's width, finite, and
    no rotation key may be a zero quaternion.
    """
    sampler = doc.json["animations"][animation]["samplers"][index]
    where = f"animations[{animation}].samplers[{index}]"
    expect_accessor_type(doc, sampler["input"], ("SCALAR",), f"{where}.input")
    times = np.asarray(read_accessor(doc, sampler["input"]), np.float64)
    if times.ndim != 1:
        raise InputError("key times are not SCALAR", source=doc.path, field=f"{where}.input", fix="re-export the file")
    bad = ~np.isfinite(times) | (times < 0)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(f"key time {k} is {times[k]}, not a finite time >= 0", source=doc.path,
                         field=f"{where}.input", fix="re-export the animation")
    if (np.diff(times) <= 0).any():
        k = int(np.argmax(np.diff(times) <= 0))
        raise InputError(f"key times are not strictly increasing (key {k + 1} at {times[k + 1]:.6g} s after "
                         f"{times[k]:.6g} s)", source=doc.path, field=f"{where}.input", fix="re-export the animation")
    values = np.asarray(read_accessor(doc, sampler["output"]), np.float64)
    values = values.reshape(len(values), -1)
    interp = sampler.get("interpolation", "LINEAR")
    per_key = 3 if interp == "CUBICSPLINE" else 1
    width = _PATH_WIDTH[path]
    if values.shape[1] != width or len(values) != per_key * len(times):
        raise InputError(f"{len(values)} output values of width {values.shape[1]} for {len(times)} keys; {interp} "
                         f"{path} needs {per_key * len(times)} of width {width}", source=doc.path,
                         field=f"{where}.output", fix="re-export the animation")
    if not np.isfinite(values).all():
        raise InputError("output values contain NaN or inf", source=doc.path, field=f"{where}.output",
                         fix="re-export the animation")
    if path == "rotation":
        keyed = values.reshape(len(times), per_key, 4)[:, per_key // 2]
        zero = np.linalg.norm(keyed, axis=1) < 1e-6
        if zero.any():
            raise InputError(f"rotation key {int(np.argmax(zero))} is a zero quaternion", source=doc.path,
                             field=f"{where}.output", fix="re-export the animation with unit quaternions")
    return times, values


def local_matrices(doc: GltfDocument, animation: int | None, t: np.ndarray) -> np.ndarray:
    """(nodes, p, 4, 4) local transforms of every node at times ``t``.

    Animated nodes take their sampled translation/rotation/scale (channels of
    the other paths keep the node's rest value); others keep their rest
    ``matrix`` or TRS. ``weights`` (morph target) channels do not move joints
    and are ignored here.
    """
    nodes = doc.json.get("nodes", [])
    p = len(t)
    trs = [node_trs(n) for n in nodes]
    animated: dict[int, dict[str, np.ndarray]] = {}
    if animation is not None:
        anim = doc.json["animations"][animation]
        for ci, ch in enumerate(anim.get("channels", [])):
            target = ch.get("target", {})
            path, node = target.get("path"), target.get("node")
            if node is None or path not in ("translation", "rotation", "scale"):
                continue
            if trs[node] is None:
                raise InputError(f"channel {ci} animates node {node}, which has a matrix", source=doc.path,
                                 field=f"animations[{animation}].channels[{ci}]",
                                 fix="re-export with TRS node transforms")
            sampler = anim["samplers"][ch["sampler"]]
            times, values = sampler_keys(doc, animation, ch["sampler"], path)
            interp = sampler.get("interpolation", "LINEAR")
            animated.setdefault(node, {})[path] = sample_sampler(times, np.asarray(values, float), interp, t,
                                                                 rotation=path == "rotation")
    local = np.empty((len(nodes), p, 4, 4))
    for i, node in enumerate(nodes):
        rest = trs[i]
        if i in animated and rest is not None:  # an animated node has TRS (a matrix raised above)
            rt, rr, rs = rest
            a = animated[i]
            local[i] = trs_matrix(a.get("translation", np.broadcast_to(rt, (p, 3))),
                                  a.get("rotation", np.broadcast_to(rr, (p, 4))),
                                  a.get("scale", np.broadcast_to(rs, (p, 3))))
        else:
            local[i] = node_matrix(node)
    return local
