"""LPVSS/LPVIO objects: save/load round trip, version refusal, frozen models, vertices."""

import json

import control
import numpy as np
import pytest

import lpvflow
from lpvflow.basis import Basis
from lpvflow.errors import DataError, ModelError
from lpvflow.lpvio import LPVIO
from lpvflow.models import LPVSS, load


def small_io():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(2, 2, 1, 1)) * 0.2
    B = np.zeros((3, 2, 1, 1))
    B[1:] = rng.normal(size=(2, 2, 1, 1))
    return LPVIO(A, B, Basis.affine().with_range(np.array([[-1.0], [1.0]])), 0.05,
                 na=np.array([[2]]), nb=np.array([[2]]), nk=np.array([[1]]),
                 u_names=["volt"], y_names=["angle"], p_names=["theta"])


def test_save_load_roundtrip_keeps_io_and_behaviour(tmp_path):
    ss = small_io().to_ss()
    ss.save(tmp_path / "m.json")
    again = lpvflow.load(tmp_path / "m.json")
    assert isinstance(again, LPVSS) and isinstance(again.io, LPVIO)
    assert again.u_names == ["volt"] and again.basis == ss.basis and again.Ts == 0.05
    rng = np.random.default_rng(1)
    u, p = rng.normal(size=(100, 1)), rng.uniform(-1, 1, size=(100, 1))
    np.testing.assert_array_equal(again.simulate(u, p), ss.simulate(u, p))
    np.testing.assert_array_equal(again.io.simulate(u, p), ss.io.simulate(u, p))
    np.testing.assert_array_equal(again.io.na, [[2]])


def test_unknown_version_and_format_are_refused(tmp_path):
    d = small_io().to_ss().to_dict()
    d["version"] = 99
    (tmp_path / "v.json").write_text(json.dumps(d))
    with pytest.raises(ModelError, match="version 99 is not supported"):
        load(tmp_path / "v.json")
    (tmp_path / "f.json").write_text(json.dumps({"format": "other/thing", "version": 1}))
    with pytest.raises(ModelError, match="unknown format"):
        load(tmp_path / "f.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ModelError, match="not a lpvflow JSON"):
        load(tmp_path / "bad.json")
    with pytest.raises(ModelError, match="does not exist"):
        load(tmp_path / "none.json")


def test_failed_save_leaves_the_old_file_intact(tmp_path):
    path = tmp_path / "m.json"
    path.write_text("precious")
    ss = small_io().to_ss()
    ss.reduction = {"bad": object()}  # not JSON-serialisable: the write fails
    with pytest.raises(TypeError):
        ss.save(path)
    assert path.read_text() == "precious"
    assert [f.name for f in tmp_path.iterdir()] == ["m.json"]


def test_frozen_model_is_a_discrete_python_control_statespace():
    ss = small_io().to_ss()
    g = ss.frozen([0.3])
    assert isinstance(g, control.StateSpace) and g.dt == 0.05
    A = ss.matrices([0.3])[0]
    np.testing.assert_array_equal(g.A, A)
    # Frozen simulation equals the LPV simulation at constant scheduling.
    u = np.random.default_rng(2).normal(size=50)
    y_lti = control.forced_response(g, U=u).outputs
    y_lpv = ss.simulate(u[:, None], np.full((50, 1), 0.3))[:, 0]
    np.testing.assert_allclose(y_lpv, y_lti, atol=1e-12)


def test_vertices_need_an_affine_basis():
    ss = small_io().to_ss()
    corners = ss.vertices()
    assert [c[0].tolist() for c in corners] == [[-1.0], [1.0]]
    quad = LPVSS(np.zeros((3, 1, 1)), np.ones((3, 1, 1)), np.ones((3, 1, 1)), np.zeros((3, 1, 1)),
                 Basis.poly(2), 1.0)
    with pytest.raises(ModelError, match="affine"):
        quad.vertices([[-1, 1]])


def test_bad_simulation_input():
    ss = small_io().to_ss()
    with pytest.raises(DataError, match="has 2 column"):
        ss.simulate(np.zeros((10, 2)), np.zeros((10, 1)))
    with pytest.raises(DataError, match="NaN"):
        ss.simulate(np.full((10, 1), np.nan), np.zeros((10, 1)))
    with pytest.raises(DataError, match="has 9 samples"):
        ss.simulate(np.zeros((9, 1)), np.zeros((10, 1)))
    for model in (small_io(), ss):  # one scheduling signal, two given: named before the basis is evaluated
        with pytest.raises(DataError, match=r"scheduling p has 2 column\(s\) but the model expects 1"):
            model.simulate(np.zeros((10, 1)), np.zeros((10, 2)))
    with pytest.raises(DataError, match="noise e has 3 column"):
        small_io().simulate(np.zeros((10, 1)), np.zeros((10, 1)), e=np.zeros((10, 3)))
    with pytest.raises(ModelError, match="shape"):
        LPVSS(np.zeros((2, 2, 2)), np.zeros((2, 3, 1)), np.zeros((2, 1, 2)), np.zeros((2, 1, 1)),
              Basis.affine(), 1.0)
