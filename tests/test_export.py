"""STL export: every printable part is a watertight solid in millimetres that a slicer accepts."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from wirecraft.assets.connectors import make_connector
from wirecraft.assets.export import export_stl, part_names


@pytest.mark.parametrize("part", part_names())
def test_part_exports_watertight_in_millimetres(part, tmp_path):
    path = export_stl(part, tmp_path / f"{part}.stl", clearance=0.003)
    mesh = trimesh.load(path, file_type="stl")  # read back with the library's own loader
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0
    # Millimetres: every part is between 5 mm and 0.5 m across.
    assert 5.0 < mesh.extents.max() < 500.0


def test_port_bore_grows_with_clearance(tmp_path):
    """The exported socket of clearance c is the plug's cross-section widened by 2c."""
    for c in (0.0005, 0.003):
        mesh = trimesh.load(export_stl("cuboid_port", tmp_path / "p.stl", clearance=c))
        connector = make_connector("cuboid", c)
        # The outer block is the cavity plus a wall; the cavity is the plug plus c per side.
        expected_width_mm = (connector.width + 2 * c + 2 * 0.004) * 1000
        assert mesh.extents[1] == pytest.approx(expected_width_mm, abs=1e-6)


def test_plug_and_port_do_not_overlap_when_seated():
    """The seated plug's shell and its socket share no volume (a printable clearance fit)."""
    connector = make_connector("ethernet", 0.0005)
    from wirecraft.assets.shapes import to_mesh

    port = to_mesh(connector.port_shapes(), scale=1000)
    shell = to_mesh(connector.plug_shell_shapes(), scale=1000)
    shell.apply_translation([(connector.cavity_depth - connector.plug_length) * 1000, 0, 0])

    def overlap_volume(shift_mm) -> float:
        moved = shell.copy()
        moved.apply_translation(shift_mm)
        overlap = trimesh.boolean.intersection([port, moved], engine="manifold")
        # Seated, the overlap is a zero-volume sliver (the faces touching at the stop), whose
        # centre of mass trimesh computes as 0 / 0 along with the volume.
        with np.errstate(invalid="ignore"):
            return float(overlap.volume)

    assert overlap_volume([0.0, 0.0, 0.0]) == pytest.approx(0.0, abs=1e-3)  # mm^3
    assert np.isclose(shell.bounds[1, 0], connector.cavity_depth * 1000)
    # The check sees a misfit: 0.5 mm past the stop, or sideways by more than the clearance.
    assert overlap_volume([0.5, 0.0, 0.0]) > 10.0
    assert overlap_volume([0.0, 0.8, 0.0]) > 10.0


def test_unknown_part_lists_valid_names(tmp_path):
    with pytest.raises(ValueError, match="displayport_port"):
        export_stl("hdmi_port", tmp_path / "x.stl")
    assert not list(tmp_path.iterdir())


def test_bad_clearance_writes_nothing(tmp_path):
    with pytest.raises(ValueError, match="clearance"):
        export_stl("cuboid_port", tmp_path / "x.stl", clearance=-0.001)
    assert not list(tmp_path.iterdir())
