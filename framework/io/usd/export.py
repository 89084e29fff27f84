"""A new UsdSkel character from a rigslim asset (a glTF skin, a libigl mesh + TGF skeleton + animation).

The stage written by :func:`build_stage`::

    /NAME              SkelRoot (defaultPrim, kind = component; upAxis, metersPerUnit on the layer)
      Skeleton         joints, bindTransforms, restTransforms, skel:animationSource -> Animation
      Animation        SkelAnimation (named after the clip): translations, rotations, scales per frame
                       (time code = frame); a glTF's other clips beside it, unbound
      MESH             Mesh: points, triangles, skel:skeleton, jointIndices/jointWeights (elementSize k)

Handle ``b`` becomes joint ``b`` (joints are listed parents first, as UsdSkel
requires; when that reorders them, the mesh's ``skel:joints`` lists them in
handle order so that ``jointIndices`` are the handle numbers). Its bind transform ``B_b`` (skeleton space)
is the glTF joint's ``IBM_b^{-1}`` when the asset was read from glTF, else the
translation to the bone's start ``joints[bones[b, 0]]``. A pose's handle
transform ``T_b`` (rigslim's ``v' = sum_b a_b T_b v``) becomes the joint's
skeleton-space transform ``S_b = T_b B_b``, so that UsdSkel's
``S_b B_b^{-1} = T_b`` reproduces the asset's deformation, and its local
transform ``L_b = S_{parent(b)}^{-1} S_b`` is stored as translation, rotation
(quatf) and scale (half3), the only form ``SkelAnimation`` has: a transform
with shear is refused with one line.
"""

from __future__ import annotations

import re

import numpy as np

from rigslim.errors import StepError
from rigslim.io.usd.stage import matrix_rows, pxr_modules, to_rows

#: Largest |R^T R - I| (after taking the scales out) a local joint transform may have: beyond it, it has shear.
SHEAR_TOLERANCE = 1e-4


def usd_identifier(name: str, taken: set[str]) -> str:
    """A valid, unused USD prim/joint name from ``name`` (letters, digits, ``_``; not starting with a digit)."""
    base = re.sub(r"[^A-Za-z0-9_]", "_", str(name)) or "joint"
    if base[0].isdigit():
        base = "_" + base
    out, i = base, 1
    while out in taken:
        out, i = f"{base}_{i}", i + 1
    taken.add(out)
    return out


def joint_tokens(names: list[str], parents: np.ndarray) -> list[str]:
    """UsdSkel joint paths (``"Hips/Spine/Chest"``) from names and parent indices (parents listed first)."""
    taken: dict[int, set[str]] = {}
    leaf = [""] * len(names)
    tokens = [""] * len(names)
    for j in _parents_first(parents):
        p = int(parents[j])
        leaf[j] = usd_identifier(names[j], taken.setdefault(p, set()))
        tokens[j] = leaf[j] if p < 0 else f"{tokens[p]}/{leaf[j]}"
    return tokens


def _parents_first(parents: np.ndarray) -> list[int]:
    order, seen = [], set()
    children: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        children.setdefault(int(p), []).append(j)
    stack = list(reversed(children.get(-1, [])))
    while stack:
        j = stack.pop()
        if j in seen:
            continue
        seen.add(j)
        order.append(j)
        stack.extend(reversed(children.get(j, [])))
    if len(order) != len(parents):
        raise StepError("the skeleton's parent links form a cycle", field="handles.parents",
                        fix="give a tree of bones")
    return order


def bind_transforms(handles, gltf_skin=None) -> np.ndarray:
    """(n, 4, 4) skeleton-space bind transforms (column convention) of the handles (module docstring)."""
    n = handles.n
    if gltf_skin is not None:
        ibm = gltf_inverse_bind_matrices(gltf_skin)
        if ibm is not None and len(ibm) == n:
            return np.linalg.inv(ibm)
    B = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    if handles.joints is not None and handles.bones is not None:
        B[:, :3, 3] = np.asarray(handles.joints)[np.asarray(handles.bones)[:, 0]]
    return B


def gltf_inverse_bind_matrices(skin) -> np.ndarray | None:
    """The (n, 4, 4) inverse bind matrices of a :class:`rigslim.io.gltf.skin.GltfSkin` (identity when unauthored)."""
    from rigslim.io.gltf.document import read_accessor

    sk = skin.document.json["skins"][skin.skin]
    n = len(skin.joints)
    if "inverseBindMatrices" not in sk:
        return np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    M = read_accessor(skin.document, sk["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
    return np.asarray(M[:n], np.float64)


def decompose(L: np.ndarray, *, where: str = "animation"):
    """Translations (n, 3), quaternions (n, 4; w, x, y, z) and scales (n, 3) of local transforms ``L = T R S``.

    The scales are the column norms of the 3x3 part (one made negative when
    its determinant is); a remaining non-orthogonal part is shear, which a
    ``SkelAnimation`` cannot hold.
    """
    from rigslim.io.transforms import matrix_quaternion

    M = L[:, :3, :3]
    s = np.linalg.norm(M, axis=1)
    if (s <= 0).any():
        raise StepError("a joint transform has a zero scale", field=where, fix="give invertible bone transforms")
    s[:, 0] *= np.where(np.linalg.det(M) < 0, -1.0, 1.0)
    R = M / s[:, None, :]
    err = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    if err.size and err.max() > SHEAR_TOLERANCE:
        j = int(np.argmax(err))
        raise StepError(f"the transform of joint {j} has shear (|R^T R - I| = {err.max():.2g}); a SkelAnimation "
                        "holds translation, rotation and scale only", field=where,
                        fix="give bone transforms without shear (or write glTF, which has the same limit)")
    s = np.where(np.abs(s - 1) < 1e-6, 1.0, s)
    q = matrix_quaternion(R)                       # x, y, z, w
    return L[:, :3, 3].copy(), np.concatenate([q[:, 3:], q[:, :3]], axis=1), s


def local_transforms(T: np.ndarray, bind: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """(p, n, 4, 4) ``L = S_parent^{-1} S`` with ``S = T B`` (module docstring), from (p, n, 3, 4) handle transforms."""
    p, n = T.shape[:2]
    T4 = np.zeros((p, n, 4, 4))
    T4[..., :3, :] = T
    T4[..., 3, 3] = 1.0
    S = T4 @ bind[None]
    L = S.copy()
    child = np.flatnonzero(parents >= 0)
    L[:, child] = np.linalg.inv(S[:, parents[child]]) @ S[:, child]
    return L


def build_stage(mesh, handles, weights, poses=None, *, fps: float = 30.0, bind=None, name: str = "Character",
                mesh_name: str = "Body", normals: bool = True, clips=None, animation_name: str = "Animation"):
    """An in-memory UsdSkel stage of one skinned mesh (module docstring).

    Parameters
    ----------
    mesh : Mesh
        Rest mesh (skeleton space at bind time: ``geomBindTransform`` is the identity).
    handles : Handles
        A skeleton (a cage cannot be UsdSkel joints).
    weights : scipy.sparse (m, n) or ReducedWeights
        Written with ``elementSize`` = the most influences of any vertex (ReducedWeights: its k).
    poses : Poses, optional
        Frame f becomes time code f; ``timeCodesPerSecond = fps``.
    bind : (n, 4, 4) array, optional
        Bind transforms; default :func:`bind_transforms`.
    clips : list of (str, Poses), optional
        More animations of the same handles, each written as a ``SkelAnimation`` named after the clip
        beside the bound one (the reader's ``animation: NAME`` samples them).

    Returns
    -------
    pxr.Usd.Stage
    """
    Usd, UsdGeom, UsdSkel, Sdf, Gf, Vt = pxr_modules()
    if handles is None or handles.is_cage:
        raise StepError("USD skins are skeletons: a cage cannot become UsdSkel joints", field="handles",
                        fix="write the cage result as .npz or .dmat")
    n = handles.n
    parents = np.asarray(handles.parents if handles.parents is not None else np.full(n, -1), np.int64)
    bind = bind_transforms(handles) if bind is None else np.asarray(bind, np.float64)
    tokens = joint_tokens(list(handles.names), parents)
    order = np.array(_parents_first(parents), np.int64)    # UsdSkel lists every parent before its children
    skel_tokens = [tokens[j] for j in order]
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root_name = usd_identifier(name, set())
    root = UsdSkel.Root.Define(stage, f"/{root_name}")
    stage.SetDefaultPrim(root.GetPrim())
    Usd.ModelAPI(root.GetPrim()).SetKind("component")
    skel = UsdSkel.Skeleton.Define(stage, f"/{root_name}/Skeleton")
    taken = {"Skeleton", mesh_name}
    bound = usd_identifier(animation_name, taken)
    skel.CreateJointsAttr(Vt.TokenArray(skel_tokens))
    skel.CreateJointNamesAttr(Vt.TokenArray([str(handles.names[j]) for j in order]))
    skel.CreateBindTransformsAttr(to_rows(bind[order]))
    rest = local_transforms(np.broadcast_to(np.eye(4)[:3], (1, n, 3, 4)), bind, parents)[0]
    skel.CreateRestTransformsAttr(to_rows(rest[order]))
    if poses is not None and len(poses):
        L = local_transforms(poses.T, bind, parents)[:, order]
        _animation(stage, skel, f"/{root_name}/{bound}", skel_tokens, L, fps)
    for clip, clip_poses in clips or []:
        L = local_transforms(clip_poses.T, bind, parents)[:, order]
        _animation(stage, None, f"/{root_name}/{usd_identifier(clip, taken)}", skel_tokens, L, fps)
    geom = UsdGeom.Mesh.Define(stage, f"/{root_name}/{usd_identifier(mesh_name, taken - {mesh_name})}")
    V, F = np.asarray(mesh.V, np.float64), np.asarray(mesh.F, np.int64)
    geom.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(V.astype(np.float32)))
    geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(F), 3, np.int32)))
    geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(F.astype(np.int32).ravel()))
    geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    geom.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(geom.GetPointsAttr().Get()))
    if normals:
        from rigslim.numerics.area_weighted_normals import area_weighted_normals

        N = area_weighted_normals(V, F)
        geom.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(N, np.float32)))
        geom.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    binding = UsdSkel.BindingAPI.Apply(geom.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    binding.CreateGeomBindTransformAttr(matrix_rows(np.eye(4)))
    if not np.array_equal(order, np.arange(n)):      # the weights index handles: name them in that order
        binding.CreateJointsAttr(Vt.TokenArray(tokens))
    set_influences(geom.GetPrim(), *fixed_width(weights))
    return stage


def _animation(stage, skel, path: str, tokens: list[str], L: np.ndarray, fps: float) -> None:
    """A SkelAnimation with one time sample per frame of the (p, n, 4, 4) local transforms."""
    Usd, _, UsdSkel, _, Gf, Vt = pxr_modules()
    anim = UsdSkel.Animation.Define(stage, path)
    anim.CreateJointsAttr(Vt.TokenArray(tokens))
    tr, ro, sc = anim.CreateTranslationsAttr(), anim.CreateRotationsAttr(), anim.CreateScalesAttr()
    for f in range(len(L)):
        t, q, s = decompose(L[f], where=f"poses (frame {f})")
        tr.Set(Vt.Vec3fArray.FromNumpy(t.astype(np.float32)), Usd.TimeCode(f))
        ro.Set(Vt.QuatfArray([Gf.Quatf(*map(float, x)) for x in q]), Usd.TimeCode(f))
        sc.Set(Vt.Vec3hArray.FromNumpy(s.astype(np.float16)), Usd.TimeCode(f))
    if skel is None:        # another clip: not bound, the stage's time range stays the bound one's
        return
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    stage.SetTimeCodesPerSecond(float(fps))
    stage.SetFramesPerSecond(float(fps))
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(max(len(L) - 1, 0))


def fixed_width(weights) -> tuple[np.ndarray, np.ndarray]:
    """(m, k) joint indices and weights of a sparse matrix or ReducedWeights (k = the most per row)."""
    import scipy.sparse as sp

    if hasattr(weights, "indices") and hasattr(weights, "values") and not sp.issparse(weights):
        return np.asarray(weights.indices, np.int64), np.asarray(weights.values, np.float64)
    from rigslim.io.gltf.write import fixed_width_weights

    reduced = fixed_width_weights(sp.csr_matrix(weights))
    return np.asarray(reduced.indices, np.int64), np.asarray(reduced.values, np.float64)


def set_influences(prim, indices: np.ndarray, values: np.ndarray, *, clamp_negative: bool = False) -> dict:
    """Author ``primvars:skel:jointIndices``/``jointWeights`` (vertex, elementSize = k) on a mesh prim.

    Weights are written as float32 rows that sum to one (the largest of each
    row absorbs the rounding: :func:`rigslim.io.gltf.write.quantize_weights`);
    negative weights are refused, or with ``clamp_negative`` set to zero and
    the row renormalised. Slots past a vertex's last influence hold joint 0
    with weight 0.
    """
    _, _, UsdSkel, _, _, Vt = pxr_modules()
    from rigslim.io.gltf.write import clamp_negative_weights, quantize_weights

    stats: dict = {}
    values = np.asarray(values, np.float64)
    if clamp_negative:
        values, stats = clamp_negative_weights(values)
    if not np.isfinite(values).all():
        raise StepError("the weights to write contain NaN or inf", field="weights", fix="check the solve step")
    Q = quantize_weights(values, "float")
    I = np.where(Q > 0, np.asarray(indices, np.int64), 0).astype(np.int32)
    k = Q.shape[1]
    api = UsdSkel.BindingAPI.Apply(prim)
    for name in ("primvars:skel:jointIndices", "primvars:skel:jointWeights"):
        if prim.HasAttribute(name):     # a different elementSize cannot be set on an existing primvar's value alone
            prim.RemoveProperty(name)
    api.CreateJointIndicesPrimvar(False, k).Set(Vt.IntArray.FromNumpy(I.ravel()))
    api.CreateJointWeightsPrimvar(False, k).Set(Vt.FloatArray.FromNumpy(Q.astype(np.float32).ravel()))
    return stats


def add_gltf_looks(stage, gltf, textures=None) -> dict:
    """UVs, normals and material slots of a glTF skin on the exported mesh (:func:`build_stage` of ``gltf.mesh``).

    - ``TEXCOORD_n`` (when every skinned primitive has it) becomes the ``faceVarying`` primvar ``st``
      (``st1``, ...), ``st = (u, 1 - v)`` (glTF's texture origin is the top left, USD's the bottom left),
      taken at each face corner's own file vertex, so UV seams stay seams;
    - ``NORMAL`` (when every skinned primitive has it) becomes the ``faceVarying`` primvar ``normals``
      (indexed), the file's own normal at each corner, replacing the welded vertex normals, so hard edges
      and the shading of the file are kept;
    - each primitive's faces become a ``GeomSubset`` of the ``materialBind`` family (a partition) bound to
      a ``Material`` named after the glTF material, with a ``UsdPreviewSurface`` carrying its base colour
      factor, metallic and roughness factors, ``opacityThreshold`` (``MASK``) and, with ``textures`` given,
      its base colour texture: the image written there (PNG or JPEG, as in the file) and read by a
      ``UsdUVTexture`` (``sourceColorSpace = sRGB``, ``scale`` = the factor, ``a`` to ``opacity`` unless
      ``OPAQUE``) at ``st`` through a ``UsdPrimvarReader_float2``. A double-sided material makes the mesh
      ``doubleSided`` and is noted in the Material's ``customData`` (``rigslim:doubleSided``: USD has no
      per-material flag; :mod:`rigslim.io.usd.looks` reads it back).

    Parameters
    ----------
    stage : pxr.Usd.Stage
    gltf : GltfSkin
    textures : path-like, optional
        Folder for the texture images (absolute paths are authored; the writer makes them relative to
        the output). None: textures are not converted.

    Returns ``{"uv_sets": n, "materials": m, "textures": t}``.
    """
    from rigslim.io.gltf.primitives import primitive_data, welded_faces

    UsdGeom = pxr_modules()[1]
    data = primitive_data(gltf)
    faces = welded_faces(gltf, data)
    geom = next(p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    sets = _corner_primvars(geom, gltf, data, faces)
    n_materials, n_textures = _bind_materials(stage, UsdGeom.Mesh(geom), gltf, data, faces, textures)
    return {"uv_sets": sets, "materials": n_materials, "textures": n_textures}


def _corner_primvars(geom, gltf, data, faces) -> int:
    """``st`` (``st1``, ...) and ``normals`` as indexed ``faceVarying`` primvars of the mesh prim ``geom``, from
    each face corner's own file vertex (:func:`add_gltf_looks`); returns the number of UV sets written."""
    _, UsdGeom, _, Sdf, _, Vt = pxr_modules()
    sets = 0

    def corners(name):
        return np.concatenate([d.attributes[name][Ff - sl.start] for d, sl, (_, Ff)
                               in zip(data, gltf.slices, faces, strict=True)]).reshape(len(gltf.mesh.F) * 3, -1)

    def indexed(name, type_name, X, decimals):
        values, index = np.unique(np.round(X, decimals), axis=0, return_inverse=True)
        pv = UsdGeom.PrimvarsAPI(geom).CreatePrimvar(name, type_name, UsdGeom.Tokens.faceVarying)
        pv.Set(Vt.Vec2fArray.FromNumpy(values.astype(np.float32)) if X.shape[1] == 2
               else Vt.Vec3fArray.FromNumpy(values.astype(np.float32)))
        pv.SetIndices(Vt.IntArray.FromNumpy(np.asarray(index, np.int32).ravel()))

    while all(f"TEXCOORD_{sets}" in d.attributes for d in data) and data:
        uv = corners(f"TEXCOORD_{sets}")
        uv = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)
        indexed("st" if sets == 0 else f"st{sets}", Sdf.ValueTypeNames.TexCoord2fArray, uv, 7)
        sets += 1
    if data and all("NORMAL" in d.attributes for d in data):
        N = corners("NORMAL")
        N = N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
        geom.RemoveProperty("normals")
        indexed("normals", Sdf.ValueTypeNames.Normal3fArray, N, 6)
    return sets


def _bind_materials(stage, mesh, gltf, data, faces, textures) -> tuple[int, int]:
    """One ``materialBind`` ``GeomSubset`` per primitive, bound to a ``UsdPreviewSurface`` material per glTF
    material (:func:`add_gltf_looks`); returns the numbers of materials and texture images written."""
    _, UsdGeom, _, _, _, Vt = pxr_modules()
    from pxr import UsdShade

    js = gltf.document.json
    root = stage.GetDefaultPrim().GetPath()
    UsdGeom.Scope.Define(stage, root.AppendChild("Looks"))
    taken: set[str] = set()
    materials: dict = {}
    images: dict = {}
    start = 0
    double = False
    for d, sl, (Fw, _) in zip(data, gltf.slices, faces, strict=True):
        m = js["meshes"][sl.mesh]["primitives"][sl.primitive].get("material")
        if m not in materials:
            spec = js.get("materials", [])[m] if m is not None else {}
            materials[m] = _preview_material(stage, root, usd_identifier(spec.get("name") or f"material{m}", taken),
                                             spec, _texture_file(gltf, spec, textures, images), _sampler(js, spec))
            double |= bool(spec.get("doubleSided"))
        subset = UsdGeom.Subset.CreateUniqueGeomSubset(
            mesh, f"primitive{d.index}", UsdGeom.Tokens.face,
            Vt.IntArray.FromNumpy(np.arange(start, start + len(Fw), dtype=np.int32)), "materialBind", "partition")
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(materials[m])
        start += len(Fw)
    if double:
        mesh.CreateDoubleSidedAttr(True)
    return len(materials), len(images)


def _sampler(js: dict, spec: dict) -> dict:
    """The sampler of a glTF material's base colour texture (``{}``: none, glTF's default: repeat)."""
    ref = spec.get("pbrMetallicRoughness", {}).get("baseColorTexture")
    if ref is None:
        return {}
    s = js.get("textures", [])[ref["index"]].get("sampler")
    return js.get("samplers", [])[s] if s is not None else {}


def _texture_file(gltf, spec: dict, folder, written: dict) -> str | None:
    """The image file of a glTF material's base colour texture, written once into ``folder`` (None: none)."""
    from rigslim.io.atomic import atomic_path

    ref = spec.get("pbrMetallicRoughness", {}).get("baseColorTexture")
    js = gltf.document.json
    if folder is None or ref is None:
        return None
    source = js.get("textures", [])[ref["index"]].get("source")
    if source is None:
        return None
    if source in written:
        return written[source]
    image = js["images"][source]
    doc = gltf.document
    data = doc.buffer_view_bytes(image["bufferView"]) if "bufferView" in image else \
        doc.uri_bytes(image["uri"], f"images[{source}]")
    ext = ".png" if data[:8] == b"\x89PNG\r\n\x1a\n" else ".jpg" if data[:3] == b"\xff\xd8\xff" else None
    if ext is None:       # glTF core images are PNG or JPEG; anything else stays behind
        return None
    from pathlib import Path

    taken = {Path(p).stem for p in written.values()}
    name = usd_identifier(image.get("name") or Path(str(image.get("uri", ""))).stem or f"image{source}", taken)
    target = Path(folder).resolve() / (name + ext)
    with atomic_path(target) as tmp:
        Path(tmp).write_bytes(data)
    written[source] = str(target)
    return written[source]


def _preview_material(stage, root, name: str, spec: dict, texture: str | None = None, sampler: dict | None = None):
    """A Material with a UsdPreviewSurface from a glTF material's factors (and base colour texture file)."""
    _, _, _, Sdf, Gf, _ = pxr_modules()
    from pxr import UsdShade

    material = UsdShade.Material.Define(stage, root.AppendChild("Looks").AppendChild(name))
    shader = UsdShade.Shader.Define(stage, material.GetPath().AppendChild("PreviewSurface"))
    shader.CreateIdAttr("UsdPreviewSurface")
    pbr = spec.get("pbrMetallicRoughness", {})
    r, g, b, a = (list(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])) + [1.0] * 4)[:4]
    mode = spec.get("alphaMode", "OPAQUE")
    diffuse = shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f)
    opacity = shader.CreateInput("opacity", Sdf.ValueTypeNames.Float)
    if texture is not None:
        reader = UsdShade.Shader.Define(stage, material.GetPath().AppendChild("TexCoordReader"))
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
        st = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
        tex = UsdShade.Shader.Define(stage, material.GetPath().AppendChild("BaseColorTexture"))
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(texture))
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(st)
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
        tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(float(r), float(g), float(b), float(a)))
        wrap = {10497: "repeat", 33648: "mirror", 33071: "clamp"}
        sampler = sampler or {}
        tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set(wrap.get(sampler.get("wrapS", 10497), "repeat"))
        tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set(wrap.get(sampler.get("wrapT", 10497), "repeat"))
        diffuse.ConnectToSource(tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
        alpha = tex.CreateOutput("a", Sdf.ValueTypeNames.Float)
        if mode != "OPAQUE":
            opacity.ConnectToSource(alpha)
        else:
            opacity.Set(1.0)
    else:
        diffuse.Set(Gf.Vec3f(float(r), float(g), float(b)))
        opacity.Set(float(a) if mode != "OPAQUE" else 1.0)
    if mode == "MASK":
        shader.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(float(spec.get("alphaCutoff", 0.5)))
    shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(float(pbr.get("metallicFactor", 1.0)))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(float(pbr.get("roughnessFactor", 1.0)))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    material.GetPrim().SetCustomDataByKey("rigslim:doubleSided", bool(spec.get("doubleSided", False)))
    return material
