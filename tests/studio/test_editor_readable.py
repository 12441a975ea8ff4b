"""Issue 44.7: the editor's weight chart reads frames on a numeric x axis labelled "frame"
(uPlot took the frame numbers for seconds since 1970 and printed "12:00am 1/1/70"), and
each control point's gizmo carries the index the "Move control point" panel moves it by."""

import jax
import numpy as np
import pytest
from helpers import face_like

import fxspace as fx
from fxspace.studio._editor import curve_axes, gizmo_label


def test_weight_chart_has_a_frame_axis_not_a_time_axis():
    opts = curve_axes(120)
    assert opts["scales"]["x"]["time"] is False  # numbers, not dates
    assert opts["scales"]["x"]["range"] == [0.0, 119.0]
    assert opts["axes"][0]["label"] == "frame" and opts["axes"][0]["scale"] == "x"
    assert opts["scales"]["y"]["range"] == [0.0, 1.05] and opts["axes"][1]["label"] == "weight"
    assert gizmo_label(7) == "#7"


@pytest.mark.slow
def test_gizmos_carry_their_index_and_the_chart_takes_the_options(tmp_path):
    pytest.importorskip("viser", reason="viser not installed (pip install -e '.[viewer]')")
    from fxspace.studio import EditorData, load_editor_data, save_editor_data, serve_editor

    _, pos = face_like(n=40, m=12, seed=3)
    surf = fx.face_surface(pos[0], 200)
    X = np.asarray(fx.rbf_deform(surf.vertices, pos[0], pos))
    fit = fx.fit_scene(X, 4, boundaries=[0, 13, 26, 39], key=jax.random.PRNGKey(0), n_init=3)
    save_editor_data(tmp_path, EditorData(X, surf.faces, fit.model, rate=30.0, gamma=0.5))
    server, ctl = serve_editor(load_editor_data(tmp_path), port=0, environment_map=False,
                               block=False)  # fmt: skip
    try:
        view = server.fxspace_view
        n = len(view.handles)
        assert n == 4 and [lb.text for lb in view.cp_labels] == [f"#{k}" for k in range(n)]
        # a label is a child of its gizmo's node, so it moves with the gizmo
        assert all(lb.name == f"/controls/cp_{k}/index" for k, lb in enumerate(view.cp_labels))
        x = np.arange(10.0)
        h = server.gui.add_uplot((x, x / 10), ({"label": "frame"}, {"label": "w"}),
                                 **curve_axes(10))  # fmt: skip
        assert h.scales["x"]["time"] is False and h.axes[0]["label"] == "frame"
    finally:
        server.stop()
