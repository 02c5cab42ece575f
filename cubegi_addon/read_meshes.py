"""One evaluated mesh to CubeGI's arrays: its corners, triangles, materials and shading
points, in bulk (``foreach_get`` into numpy; nothing loops over vertices in Python). Read
for :mod:`.scene_data`.

Shading points: CubeGI computes light at one point per distinct (vertex, corner normal,
material) of each mesh, so a flat-shaded corner gets the light of each of its faces (as a
Cycles bake of the face corners does); a vertex's value is the mean over its corners.
"""

import numpy as np

from ..cubegi_engine.geometry import mix64
from . import read_materials


def corner_vertices(mesh):
    """``(corners,)`` int64: each corner's vertex (the ``.corner_vert`` attribute where
    Blender lists it, 200 times faster than ``loops``' ``vertex_index``)."""
    out = np.empty(len(mesh.loops), dtype=np.int32)
    attr = mesh.attributes.get(".corner_vert")
    if attr is not None and attr.domain == "CORNER" and attr.data_type == "INT":
        attr.data.foreach_get("value", out)
    else:
        mesh.loops.foreach_get("vertex_index", out)
    return out.astype(np.int64)


def vertex_positions(mesh):
    """``(vertices, 3)`` float64 object-space positions (read as the float32 Blender stores:
    a float64 buffer takes Blender's slow path, 3 times slower)."""
    co = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def _triangle_materials(mesh):
    """``(triangles,)`` int64: each loop triangle's material index (its face's)."""
    tri_face = np.empty(len(mesh.loop_triangles), dtype=np.int32)
    mesh.loop_triangle_polygons.foreach_get("value", tri_face)
    attr = mesh.attributes.get("material_index")
    if attr is None or attr.domain != "FACE":
        return np.zeros(len(tri_face), dtype=np.int64)
    face_mat = np.empty(len(mesh.polygons), dtype=np.int32)
    attr.data.foreach_get("value", face_mat)
    return face_mat[tri_face].astype(np.int64)


def mesh_arrays(ob_eval, matrix, notes):
    """World-space corner data of one evaluated object, or None if it has no triangles."""
    mesh = ob_eval.to_mesh()
    try:
        mesh.calc_loop_triangles()
        t = len(mesh.loop_triangles)
        if t == 0:
            return None
        nv, nl = len(mesh.vertices), len(mesh.loops)
        local_co = vertex_positions(mesh)
        tri_loops = np.empty(t * 3, dtype=np.int32)
        mesh.loop_triangles.foreach_get("loops", tri_loops)
        tri_mat = _triangle_materials(mesh)
        loop_vertex = corner_vertices(mesh)
        cn = np.empty(nl * 3, dtype=np.float32)
        mesh.corner_normals.foreach_get("vector", cn)

        m = np.array(matrix, dtype=np.float64)
        co = local_co @ m[:3, :3].T + m[:3, 3]
        normal_m = np.linalg.inv(m[:3, :3]).T if abs(np.linalg.det(m[:3, :3])) > 1e-300 else m[:3, :3]
        tri_loops = tri_loops.reshape(-1, 3).astype(np.int64)
        if np.linalg.det(m[:3, :3]) < 0:  # mirrored: keep front faces front
            tri_loops = tri_loops[:, ::-1]

        # Material of each corner (a corner's material is its face's).
        loop_mat = np.zeros(nl, dtype=np.int64)
        loop_mat[tri_loops.ravel()] = np.repeat(tri_mat, 3)
        albedo = np.empty((nl, 3))
        emission = np.empty((nl, 3))
        sent = np.empty((nl, 3))
        slots = [s.material for s in ob_eval.material_slots] or [None]
        used = np.flatnonzero(np.bincount(loop_mat))
        for mi in used:
            ids = np.arange(nl) if len(used) == 1 else np.flatnonzero(loop_mat == mi)
            mat = slots[mi] if mi < len(slots) else None
            rows = slice(None) if len(used) == 1 else ids
            albedo[rows], emission[rows], sent[rows] = read_materials.material_corners(mat, mesh, ids, loop_vertex, notes)
        np.clip(albedo, 0.0, 1.0, out=albedo)
        np.clip(sent, 0.0, 1.0, out=sent)
        np.maximum(emission, 0.0, out=emission)
        return {
            "co": co,
            "local_co": local_co,
            "loop_vertex": loop_vertex,
            "corner_normal": cn.reshape(-1, 3),  # object space until shading_points turns it (numpy alone)
            "normal_matrix": normal_m,
            "tri_loops": tri_loops,
            "loop_mat": loop_mat,
            "albedo": albedo,
            "emission": emission,
            "sent": sent,
            "vertex_count": nv,
        }
    finally:
        ob_eval.to_mesh_clear()


def shading_points(data):
    """Merge corners that share vertex, normal and material into shading points."""
    if "normal_matrix" in data:  # corner normals to world space, unit length
        cn = data["corner_normal"] @ data.pop("normal_matrix").T
        cn /= np.maximum(np.linalg.norm(cn, axis=1, keepdims=True), 1e-300)
        data["corner_normal"] = cn
    first, inverse = _groups(data["loop_vertex"], np.round(data["corner_normal"] * 1e4).astype(np.int64), data["loop_mat"])
    count = np.bincount(inverse).astype(np.float64)[:, None]

    def mean(values):
        return np.stack([np.bincount(inverse, values[:, c], minlength=len(first)) for c in range(3)], axis=1) / count

    normals = mean(data["corner_normal"])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    return {
        "points": data["co"][data["loop_vertex"][first]],
        "normals": normals,
        "albedo": mean(data["albedo"]),
        "emission": mean(data["emission"]),
        "sent": mean(data["sent"]),
        "triangles": inverse[data["tri_loops"]],
        "loop_point": inverse,
    }


def _is_open(data):
    """Whether the mesh has an edge that only one of its faces uses (a sheet: a plane, a
    slat, a lamp's quad), by where its vertices stand (shading points split at seams, and a
    box whose sides are separate pieces meeting at its edges, are closed)."""
    if not len(data["tri_loops"]):
        return False
    tri = _welded(data["co"])[data["loop_vertex"][data["tri_loops"]]]
    a = tri.ravel()
    b = np.roll(tri, -1, axis=1).ravel()
    edges = np.minimum(a, b) * (int(tri.max()) + 1) + np.maximum(a, b)
    edges.sort()
    single = np.ones(len(edges), dtype=bool)
    same = edges[1:] == edges[:-1]
    single[1:] &= ~same
    single[:-1] &= ~same
    return bool(single.any())


def _welded(co):
    """``(vertices,)`` a label per position, equal for vertices that stand at one spot (as
    ``np.unique(co, axis=0, return_inverse=True)`` labels them, ten times faster: one sort
    of a 64-bit hash of each position, checked, and the row sort where two positions share
    a hash)."""
    exact = co + 0.0  # -0.0 and 0.0 are one position
    bits = exact.view(np.uint64)
    h = mix64(bits[:, 0])
    h = mix64(h ^ bits[:, 1])
    h = mix64(h ^ bits[:, 2])
    _, first, labels = np.unique(h, return_index=True, return_inverse=True)
    labels = labels.ravel()
    if not np.array_equal(exact[first][labels], exact):  # a shared hash (or a NaN)
        labels = np.unique(exact, axis=0, return_inverse=True)[1].ravel()
    return labels


def with_back_side(pts, data):
    """An open mesh's shading points with their back side added: Cycles shades both sides of
    a surface, so each point of a sheet gets a twin facing the other way (its light is not
    written; it lights others), and each triangle a twin over them, wound the other way
    (see ``SceneArrays.back``). A closed mesh keeps one side (its inside is no surface)."""
    n = len(pts["points"])
    pts["back"] = np.zeros(n, dtype=bool)
    if not _is_open(data):
        return pts
    for key in ("points", "albedo", "emission", "sent"):
        pts[key] = np.concatenate([pts[key], pts[key]])
    pts["normals"] = np.concatenate([pts["normals"], -pts["normals"]])
    pts["triangles"] = np.concatenate([pts["triangles"], pts["triangles"][:, ::-1] + n])
    pts["back"] = np.concatenate([pts["back"], np.ones(n, dtype=bool)])
    return pts


def _groups(vertex, normal, material):
    """``np.unique`` of the rows (vertex, normal x, y, z, material) with ``return_index`` and
    ``return_inverse``, in its order, by one stable sort on three integer keys (the normal's
    components, within +-10,000, packed into one): five times faster than sorting rows."""
    packed = ((normal[:, 0] + 16384) << 30) | ((normal[:, 1] + 16384) << 15) | (normal[:, 2] + 16384)
    order = np.lexsort((material, packed, vertex))
    change = np.zeros(len(order), dtype=bool)  # a group starts where any key changes
    change[:1] = True
    for key in (vertex, packed, material):
        k = key[order]
        change[1:] |= k[1:] != k[:-1]
    inverse = np.empty(len(order), dtype=np.int64)
    inverse[order] = np.cumsum(change) - 1
    return order[change], inverse


def same_vertices(mesh, data):
    """True if the evaluated mesh's vertices are the original mesh's, one for one, so its
    light can be written to them: its corners name the same vertices (modifiers that only
    move vertices), or its vertices stand where the original's do (modifiers that only
    change faces: Triangulate). False if modifiers add, remove or reorder vertices (a Sort
    Elements node keeps the count but not the order)."""
    if data["vertex_count"] != len(mesh.vertices):
        return False
    if len(data["loop_vertex"]) == len(mesh.loops) and np.array_equal(corner_vertices(mesh), data["loop_vertex"]):
        return True
    return bool(np.array_equal(vertex_positions(mesh), data["local_co"]))
