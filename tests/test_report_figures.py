"""Figures and the HTML page: the files exist, the PNGs are not blank, the page links them."""
import numpy as np
import pytest

from electrosense.meshes.pose import Pose
from electrosense.meshes.render import can_render_3d
from electrosense.meshes.sensor import preset
from electrosense.meshes.tank import Tank
from electrosense.validation.report import Figure, Section, Table, write_html
from electrosense.validation.report.figures import (
    Panel,
    Series,
    bar_figure,
    curves_figure,
    path_coordinate,
    png_is_blank,
    relative_error_figure,
    resistance_figure,
    scene_figure,
)


def _curves():
    x = np.linspace(-0.38, 0.38, 30)
    R = np.column_stack([600 + 2000 * x**4, 900 + 3000 * x**4])
    return x, R


def test_resistance_and_error_figures(tmp_path):
    x, R = _curves()
    bench = 1.02 * R
    p1 = resistance_figure(x, bench, {"bem": R, "psm": 1.01 * R}, (1, 2), tmp_path / "r.png",
                           corrected_bench_ohm=bench / 1.02)
    p2 = relative_error_figure(x, {"BEM vs bench": R / bench - 1, "PSM vs BEM": np.full_like(R, 0.01)},
                               (1, 2), tmp_path / "e.png")
    p3 = bar_figure(["mid-tank", "near wall_x+"], {"BEM": [1.0, 2.0], "PSM": [1.5, 2.5]}, tmp_path / "b.png",
                    "mean abs. error by region", "mean abs. error (%)")
    for p in (p1, p2, p3):
        assert p.exists() and p.stat().st_size > 1000
        assert not png_is_blank(p)


def test_blank_detector(tmp_path):
    from electrosense.validation.report.style import new_figure, save

    fig, axes = new_figure(1, 1)
    axes[0, 0].set_axis_off()
    assert png_is_blank(save(fig, tmp_path / "blank.png", vector=None))


def test_series_and_panel_errors(tmp_path):
    with pytest.raises(ValueError, match="values but y has"):
        Series([0, 1], [0, 1, 2], "bad")
    with pytest.raises(ValueError, match="at least one panel"):
        curves_figure([], tmp_path / "x.png")
    with pytest.raises(ValueError, match="legend_loc"):
        curves_figure([Panel("t", "x (m)", "y", [Series([0, 1], [0, 1], "a")], legend_loc="sideways")],
                      tmp_path / "x.png")


def test_path_coordinate():
    x = np.linspace(-0.3, 0.3, 7)
    poses = np.column_stack([x, np.zeros(7), np.zeros(7), np.zeros(7)])
    s, label = path_coordinate(poses)
    np.testing.assert_allclose(s, x)
    assert label.startswith("sensor position x")
    diag = np.column_stack([x, x, np.zeros(7), np.zeros(7)])
    s, label = path_coordinate(diag)
    np.testing.assert_allclose(s, np.sqrt(2) * (x - x[0]))
    assert "distance" in label


@pytest.mark.skipif(not can_render_3d(), reason="no offscreen OpenGL (EGL or OSMesa) for VTK here")
def test_scene_figure(tmp_path):
    from electrosense.meshes.sensor_mesh import mesh_sensor

    mesh = mesh_sensor(preset("angels-4"))
    x = np.linspace(-0.3, 0.3, 10)
    traj = np.column_stack([x, 0 * x, 0 * x])
    p = scene_figure(tmp_path / "scene.png", mesh, Pose(0.1, 0, 0, 0), Tank((1.0, 1.0, 1.0)), traj, np.abs(x))
    assert p.exists() and not png_is_blank(p)


def test_html_page(tmp_path):
    x, R = _curves()
    fig = resistance_figure(x, R, {"bem": R}, (1, 2), tmp_path / "figs" / "r.png")
    page = write_html(
        tmp_path / "index.html",
        "Validation <test>",
        [Section("Errors", ["one", "two"], tables=[Table(["model", "mean (%)"], [["BEM", 2.0612345]], "cap")],
                 figures=[Figure(fig, "resistance")], notes=["a note"])],
        footer="made by a test",
    )
    text = page.read_text()
    assert '<img src="figs/r.png"' in text
    assert "Validation &lt;test&gt;" in text
    assert "2.061" in text and "a note" in text
    assert "http" not in text  # offline: no external assets
    embedded = write_html(tmp_path / "embedded.html", "t", [Section("s", figures=[Figure(fig)])], embed=True)
    assert "data:image/png;base64," in embedded.read_text()
    with pytest.raises(ValueError, match="row 0 has 1 cells"):
        Table(["a", "b"], [[1]])
    with pytest.raises(ValueError, match="does not exist"):
        write_html(tmp_path / "bad.html", "t", [Section("s", figures=[Figure(tmp_path / "missing.png")])])


def test_current_lines_follow_the_field():
    from electrosense.validation.report.figures import current_lines

    x = np.linspace(-1, 1, 41)
    y = np.linspace(-1, 1, 41)
    E = np.zeros((41, 41, 2))
    E[..., 0] = 1.0  # uniform field along +x: straight lines at constant y
    lines = current_lines(x, y, E, [[-0.9, 0.3], [-0.9, -0.5]])
    assert len(lines) == 2
    for line, y0 in zip(lines, (0.3, -0.5)):
        np.testing.assert_allclose(line[:, 1], y0, atol=1e-12)
        assert np.all(np.diff(line[:, 0]) > 0) and line[-1, 0] > 0.9


def test_potential_figure_of_a_dipole(tmp_path):
    from electrosense.validation.report.figures import potential_figure

    x = np.linspace(-0.15, 0.15, 61)
    y = np.linspace(-0.1, 0.1, 41)
    X, Y = np.meshgrid(x, y)
    r_plus = np.hypot(X + 0.0925, Y)
    r_minus = np.hypot(X - 0.0925, Y)
    phi = 0.01 / r_plus - 0.01 / r_minus
    phi[(np.abs(X) < 0.1) & (np.abs(Y) < 0.01)] = np.nan  # the body
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    seeds = np.column_stack([-0.09 + 0.02 * np.cos(t), 0.02 * np.sin(t)])
    p = potential_figure(tmp_path / "phi.png", x, y, phi, seeds_m=seeds, title="dipole")
    assert p.exists() and not png_is_blank(p)
    with pytest.raises(ValueError, match="expected \\(ny, nx\\)"):
        potential_figure(tmp_path / "bad.png", x, y, phi.T)


def test_field_helpers_geometry():
    from electrosense.validation.simulation.field import (
        electrode_seeds_xy,
        inside_sensor,
        sensor_outline_xy,
        tank_walls_xy,
    )

    sensor = preset("angels-4")
    pose = Pose(-0.38, 0.0, 0.0, 0.0)
    walls = tank_walls_xy(Tank((1.0, 1.0, 1.0)), (-0.495, -0.23), (-0.1, 0.1), tolerance_m=0.0075)
    assert len(walls) == 1 and np.allclose(walls[0][:, 0], -0.5)
    assert tank_walls_xy(None, (0, 1), (0, 1)) == []
    outline = sensor_outline_xy(sensor, pose)
    assert np.isclose(outline[:, 0].max(), -0.38 + 0.1) and np.isclose(outline[:, 0].min(), -0.38 - 0.1)
    seeds = electrode_seeds_xy(sensor, pose, sensor.emitter, offset_m=0.005)
    pts = pose.to_sensor(np.column_stack([seeds, np.zeros(len(seeds))]))
    assert not inside_sensor(sensor, pts).any()  # seeds lie in the water
    assert inside_sensor(sensor, np.zeros((1, 3))).all()


def test_figures_come_with_a_vector_copy_and_the_legend_off_the_data(tmp_path):
    """A PDF beside each PNG; the shared legend sits above every panel, never over the curves."""
    from electrosense.validation.report.figures import Panel, Series
    from electrosense.validation.report.style import new_figure

    x, R = _curves()
    p = resistance_figure(x, 1.02 * R, {"bem": R, "psm": 1.01 * R}, (1, 2), tmp_path / "r.png")
    assert p.with_suffix(".pdf").read_bytes()[:5] == b"%PDF-"
    # the same drawing, kept in memory: the legend's box lies above the axes' boxes
    from electrosense.validation.report import figures

    fig, axes = new_figure(1, 2)
    panels = [Panel(f"receiver {k}", "x (m)", "U/I (ohm)", [Series(x, R[:, j], "BEM", colour="b"),
                                                              Series(x, R[:, j], "a much longer label")])
              for j, k in enumerate((1, 2))]
    for ax, panel in zip(axes.flat, panels):
        figures._draw_panel(ax, panel)
    figures._shared_legend(fig, list(zip(axes.flat, panels)))
    fig.canvas.draw()
    legend = fig.legends[0].get_window_extent()
    for ax in axes.flat:
        box = ax.get_window_extent()
        assert legend.y0 >= box.y1 - 1  # above the data
    assert legend.x0 >= 0 and legend.x1 <= fig.bbox.x1 + 1  # not clipped at the sides


def test_passes_get_a_row_each(tmp_path):
    x = np.tile(np.linspace(-0.3, 0.3, 8), 3)
    passes = np.repeat([0, 1, 2], 8)
    R = np.column_stack([600 + 100 * x**2, 700 + 100 * x**2])
    p = relative_error_figure(x, {"BEM / bench - 1": R / R.mean() - 1}, (1, 2), tmp_path / "e.png", passes=passes,
                              noise=0.001)
    from matplotlib.image import imread

    img = imread(str(p))
    assert img.shape[0] > img.shape[1]  # three rows of two panels (one row would be wide and low)
    assert not png_is_blank(p)


def test_bar_figure_counts_log_scale_and_horizontal_labels(tmp_path):
    p = bar_figure(["near wall_x-", "mid-tank"], {"BEM / bench": [0.01, 2.0]}, tmp_path / "b.png", "by region",
                   "mean |simulation / bench - 1| (%)", counts=[12, 40], lines={"noise (1 sigma)": 0.05})
    assert not png_is_blank(p) and p.with_suffix(".pdf").exists()
    names = [f"candidate_{i}" for i in range(9)]
    p = bar_figure(names, {"held-out gap (%)": np.geomspace(0.05, 400, 9)}, tmp_path / "rank.png", "ranking",
                   "held-out RMS gap (%)", lines={"noise": 0.06})
    from matplotlib.image import imread

    h, w = imread(str(p)).shape[:2]
    assert h > 300 and w > 600
    with pytest.raises(ValueError, match="2 counts for 3 categories"):
        bar_figure(["a", "b", "c"], {"v": [1, 2, 3]}, tmp_path / "x.png", "t", "y", counts=[1, 2])


def test_symmetric_colour_range_has_a_noise_floor():
    from electrosense.validation.report.style import symmetric_limit

    rng = np.random.default_rng(3)
    noise = 1e-6 * rng.standard_normal(500)
    assert symmetric_limit(noise, floor=0.01) == 0.01  # round-off is not stretched over the whole scale
    signal = np.r_[noise, -3.0, 5.0]
    assert symmetric_limit(signal, floor=0.01, percentile=100) == 5.0


def test_potential_figure_masks_the_sensor_by_its_outline(tmp_path):
    """The cells left NaN inside the body are covered by the exact outline, not drawn as blocks."""
    from electrosense.validation.report.figures import _fill_outside, potential_figure

    sensor = preset("angels-2")
    from electrosense.validation.simulation.field import electrode_segments_xy, inside_sensor, sensor_outline_xy

    pose = Pose(0.0, 0.0, 0.0, 0.0)
    x = np.linspace(-0.15, 0.15, 31)
    y = np.linspace(-0.1, 0.1, 21)
    X, Y = np.meshgrid(x, y)
    phi = X.copy()
    inside = inside_sensor(sensor, np.stack([X, Y, 0 * X], axis=-1), margin_m=0.002)
    phi[inside] = np.nan
    filled = _fill_outside(phi)
    assert np.isfinite(filled).all() and np.array_equal(filled[~inside], phi[~inside])
    p = potential_figure(tmp_path / "phi.png", x, y, phi, sensor_outline_xy(sensor, pose),
                         electrode_segments_xy(sensor, pose), emitter=sensor.emitter)
    assert not png_is_blank(p) and p.with_suffix(".pdf").exists()


def test_path_coordinate_restarts_at_each_pass():
    t = np.linspace(0, 0.3, 4)
    leg = np.column_stack([t, t, 0 * t, 0 * t])
    poses = np.vstack([leg, leg + [0.0, 0.05, 0, 0]])
    s, label = path_coordinate(poses, passes=np.repeat([1, 2], 4))
    assert label == "distance along the pass (m)"
    np.testing.assert_allclose(s[:4], s[4:])
    assert s[0] == 0.0
