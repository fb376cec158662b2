import numpy as np
import pytest
import trimesh

import warp_stokes as ws
from conftest import DATA, EXAMPLE


def test_obj_keeps_file_vertex_order():
    s = ws.load_surface(EXAMPLE / "arm.obj")
    first = [ln.split()[1:4] for ln in open(EXAMPLE / "arm.obj") if ln.startswith("v ")]
    assert s.vertices.shape == (2089, 3)
    np.testing.assert_array_equal(s.vertices, np.array(first, dtype=float))
    assert s.faces.shape == (4156, 3)


@pytest.mark.parametrize("ext", ["ply", "off", "stl", "glb", "obj"])
def test_formats_round_trip(tmp_path, ext):
    cage = ws.load_surface(EXAMPLE / "arm_cage.obj")
    path = tmp_path / f"cage.{ext}"
    trimesh.Trimesh(cage.vertices, cage.faces, process=False).export(path)
    back = ws.load_surface(path)
    if ext == "stl":  # STL stores triangle soups: compare the triangles, not the vertex list
        np.testing.assert_allclose(back.vertices[back.faces], cage.vertices[cage.faces], rtol=1e-6, atol=1e-5)
    else:
        np.testing.assert_allclose(back.vertices, cage.vertices, rtol=1e-6, atol=1e-5)
        np.testing.assert_array_equal(back.faces, cage.faces)


def test_trimesh_and_arrays():
    m = trimesh.creation.icosphere(subdivisions=1)
    a = ws.load_surface(m)
    b = ws.load_surface((m.vertices, m.faces))
    np.testing.assert_array_equal(a.vertices, m.vertices)
    np.testing.assert_array_equal(b.faces, m.faces)
    assert ws.load_surface((m.vertices, None)).faces.shape == (0, 3)


def test_quads_are_fan_triangulated_like_the_reference_split():
    if not (DATA / "ogre_qmvc" / "Ogre_Cage.obj").exists():
        pytest.skip(f"test data not found: {DATA / 'ogre_qmvc'} (set WARP_STOKES_DATA)")
    quads = ws.load_surface(DATA / "ogre_qmvc" / "Ogre_Cage.obj")
    tris = ws.load_surface(DATA / "ogre_qmvc" / "cage_tri.obj")
    np.testing.assert_array_equal(quads.vertices, tris.vertices)
    np.testing.assert_array_equal(quads.faces, tris.faces)


def test_polygon_list_input():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 1.5, 0]], float)
    s = ws.load_surface((v, [[0, 1, 2, 4, 3], [0, 1, 2]]))
    assert s.faces.tolist() == [[0, 1, 2], [0, 2, 4], [0, 4, 3], [0, 1, 2]]
    # the same polygons as a numpy array of arrays (what a ragged np.array(..., dtype=object) holds)
    ragged = np.empty(2, dtype=object)
    ragged[0], ragged[1] = np.array([0, 1, 2, 4, 3]), np.array([0, 1, 2])
    assert ws.load_surface((v, ragged)).faces.tolist() == s.faces.tolist()


@pytest.mark.parametrize(
    "source, message",
    [
        ("does/not/exist.obj", "no such file"),
        ((np.zeros((0, 3)), None), "no vertices"),
        ((np.array([[0, 0, np.nan]]), None), "non-finite"),
        ((np.zeros((3, 2)), None), "shape (V, 3)"),
        ((np.eye(3), [[0, 1, 5]]), "only 3 vertices"),
        ((np.eye(3), [[0, 1]]), "at least 3"),
        (42, "expected a path"),
    ],
)
def test_bad_input_names_the_problem(source, message):
    with pytest.raises(ws.MeshError, match=message.replace("(", r"\(").replace(")", r"\)")):
        ws.load_surface(source)


def test_unreadable_and_empty_files_name_the_file(tmp_path):
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"\x00\x01not a mesh at all")
    with pytest.raises(ws.MeshError, match="garbage.ply"):
        ws.load_surface(garbage)
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing here\n")
    with pytest.raises(ws.MeshError, match="empty.obj: the file has no vertices"):
        ws.load_surface(empty)
    with pytest.raises(ws.MeshError, match="a folder, not a mesh file"):
        ws.load_surface(tmp_path)
    broken = tmp_path / "broken.obj"
    broken.write_text("v 0 0 0\nv 1 zero 0\n")
    with pytest.raises(ws.MeshError, match="broken.obj: line 2"):
        ws.load_surface(broken)


def test_fast_and_general_obj_paths_agree(tmp_path, monkeypatch):
    from warp_stokes.io import obj

    # plain triangles take the fast path, with LF or CRLF line ends; the general one reads them the same
    text = (EXAMPLE / "arm.obj").read_text()
    crlf = tmp_path / "arm_crlf.obj"
    crlf.write_bytes(text.replace("\n", "\r\n").encode())
    assert obj._read_obj_triangles(text) is not None and obj._read_obj_triangles(crlf.read_text()) is not None
    fast = [ws.load_surface(p) for p in (EXAMPLE / "arm.obj", crlf)]
    monkeypatch.setattr(obj, "_read_obj_triangles", lambda text: None)
    general = ws.load_surface(EXAMPLE / "arm.obj")
    for surface in fast:
        np.testing.assert_array_equal(surface.vertices, general.vertices)
        np.testing.assert_array_equal(surface.faces, general.faces)
    monkeypatch.undo()
    # records the fast path cannot take (a v/vt/vn corner, a quad, a vertex with colours, a negative index, a vertex
    # without coordinates) go to the general one
    for odd in ("f 1/1/1 2/2/2 3/3/3\n", "f 1 2 3 4\n", "v 0 0 0 1 0 0\nf 1 2 3\n", "f -4 -3 -2\n",
                "v # a record without coordinates (numpy skips it: the faces after it would shift)\nf 1 2 3\n"):
        assert obj._read_obj_triangles("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n" + odd) is None, odd
    mixed = tmp_path / "mixed.obj"
    mixed.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1/1/1 2/2/2 3/3/3\nf 1 3 4 2\n")
    assert ws.load_surface(mixed).faces.tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 1]]


def test_general_obj_path_reads_polygons_corners_normals_and_uvs(tmp_path):
    # everything the fast path leaves to the general one, in one file: a triangle, a quad and a pentagon; v, v/vt,
    # v//vn and v/vt/vn corners; negative indices (relative to the vertices read so far); vertex colours; tabs and
    # CRLF line ends; comments, groups and smoothing records between
    text = ("# a polygon soup\r\nv 0 0 0 1 0 0\r\nv 1 0 0\r\nv 1 1 0\r\nv\t0 1 0\r\n"
            "vt 0 0\r\nvt 1 0\r\nvt 1 1\r\nvt 0 1\r\nvn 0 0 1\r\nvn 0 0 -1\r\n"
            "g front\r\ns 1\r\nf 1/1/1 2/2/1 3/3/1\r\nf -4/1/1 -2/3/1 -1/4/1 -3/2/1\r\n"
            "v 2 0 0\r\nf 2/2/1 5/1/2 3/3/1 4/4/1 1/1/1\r\n")
    path = tmp_path / "soup.obj"
    path.write_bytes(text.encode())
    surface = ws.load_surface(path)
    np.testing.assert_array_equal(surface.vertices, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]])
    assert surface.face_counts.tolist() == [3, 4, 5]
    assert surface.face_indices.tolist() == [0, 1, 2, 0, 2, 3, 1, 1, 4, 2, 3, 0]
    assert surface.faces.tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 4, 2], [1, 2, 3], [1, 3, 0]]
    # per-vertex normals: the sum of the vertex's corner normals, normalised (vertex 4 only in the last face)
    np.testing.assert_allclose(surface.normals, [[0, 0, 1]] * 4 + [[0, 0, -1]])
    st, st_indices = surface.uvs
    np.testing.assert_array_equal(st, [[0, 0], [1, 0], [1, 1], [0, 1]])
    assert st_indices.tolist() == [0, 1, 2, 0, 2, 3, 1, 1, 0, 2, 3, 0]
    # a corner without texture coordinates drops them all, with a warning naming the file
    path.write_bytes(text.replace("f 1/1/1 2/2/1 3/3/1", "f 1//1 2//1 3//1").encode())
    with pytest.warns(UserWarning, match="soup.obj: the texture coordinates"):
        assert ws.load_surface(path).uvs is None
    # a polygon that names a vertex the file does not have is named by its number among the faces (not its fan
    # triangles'), with sizes mixed or not
    for faces in ("f 1 2 3\nf 1 3 4 9\n", "f 1 2 3 4\nf 1 3 4 9\n"):
        path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n" + faces)
        with pytest.raises(ws.MeshError, match=r"soup.obj: face 1 refers to vertex 8, but there are only 4 vertices"):
            ws.load_surface(path)


@pytest.mark.parametrize("text, faces, uvs", [
    # a byte-order mark is not part of the first record
    ("\ufeffv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n", [[0, 1, 2], [0, 2, 3]], False),
    # form feeds and Unicode line breaks end lines, as Python's splitlines has them
    ("v 0 0 0\nv 1 0 0\nv 1 1 0\x0cv 0 1 0\nf 1 2 3 4\u2028f 1 2 4\n", [[0, 1, 2], [0, 2, 3], [0, 1, 3]], False),
    # a slash after a corner's last field leaves its texture coordinates as they are
    ("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 1\nvn 0 0 1\nf 1/1/1/ 2/2/1/ 3/1/1/ 4/2/1/\n",
     [[0, 1, 2], [0, 2, 3]], True),
])
def test_general_obj_path_reads_what_exporters_write(tmp_path, text, faces, uvs):
    path = tmp_path / "odd.obj"
    path.write_bytes(text.encode())
    surface = ws.load_surface(path)
    assert surface.faces.tolist() == faces and len(surface.vertices) == 4
    assert (surface.uvs is not None) == uvs
    if uvs:
        assert surface.uvs[1].tolist() == [0, 1, 0, 1]
