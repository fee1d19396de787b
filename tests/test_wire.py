"""The wire module's bulk encoder gives exactly the maps `pack` gives."""

from __future__ import annotations

import numpy as np

from zenoh_track.adapter.encode import pack_displays, pack_frame, pack_tracks
from zenoh_track.estimation.imm import ModeProbabilities
from zenoh_track.wire import pack, unpack


def test_pack_displays_decodes_to_the_same_maps_as_pack():
    rng = np.random.default_rng(3)
    ids = ["a", "swarm-00012", "x" * 40, "t_7"]  # fixstr and str8 lengths
    n = len(ids)
    pos, vel = rng.normal(size=(n, 3)) * 1e5, rng.normal(size=(n, 3))
    pos[0, 2] = vel[0, 2] = 0.0  # a 2-D track
    sigma, age = rng.random(n), np.array([0.0, 1e-9, 3.5, 1e6])
    status = ["tentative", "confirmed", "coasting", "confirmed"]
    shown = ["prediction", "blend", "smoothed", "prediction"]
    got = pack_displays(123.25, ids, pos, vel, sigma, age, status, shown)
    for i in range(n):
        want = {"t": 123.25, "id": ids[i], "pos": pos[i].tolist(), "vel": vel[i].tolist(),
                "sigma": float(sigma[i]), "status": status[i], "age": float(age[i]),
                "shown": shown[i]}
        assert unpack(got[i]) == unpack(pack(want))
        assert list(unpack(got[i]))[0] == "t"  # t first, as every message
    assert pack_displays(1.0, [], np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0),
                         np.zeros(0), [], []) == []


def test_pack_tracks_decodes_to_the_same_maps_as_pack():
    rng = np.random.default_rng(4)
    n, k = 3, 6
    t, x, p = rng.random(n) * 100, rng.normal(size=(n, k)), rng.normal(size=(n, k * k))
    pos, vel = x[:, :3], x[:, 3:]
    mixed = ["a", "b-2", "c_3"]
    nis, updates = rng.random(n), np.array([1, 2, 70000])
    imm = ModeProbabilities(["quiet", "cv", "ca"], np.array(  # the IMM's: one map layout
        [[0.5, 0.25, 0.25], [1e-300, 1.0, 0.0], [0.1, 0.2, 0.7]]))
    same = ["a-1", "b-2", "c_3"]  # ids of one length: each body one slice of the rows
    for ids, models in ((mixed, ["cv", {"cv": 0.7, "ct+": 0.3}, "ca"]), (mixed, imm),
                        (same, imm)):
        got = pack_tracks(t, ids, pos, vel, x, p, models, nis, updates)
        for i in range(n):
            want = {"t": float(t[i]), "id": ids[i], "pos": pos[i].tolist(),
                    "vel": vel[i].tolist(), "x": x[i].tolist(), "P": p[i].tolist(),
                    "model": models[i], "nis": float(nis[i]), "updates": int(updates[i])}
            body = unpack(got[i])
            assert body == unpack(pack(want))
            assert type(body["updates"]) is int and list(body)[0] == "t"
            if models is imm:
                assert list(body["model"]) == ["quiet", "cv", "ca"]  # the modes in order


def test_pack_frame_decodes_to_the_same_map_as_pack():
    ids = ["a", "b" * 40]
    pos, vel, sigma = np.arange(6.0).reshape(2, 3), -np.arange(6.0).reshape(2, 3), np.ones(2)
    status = np.array([1, 2], np.uint8)
    want = {"t": 2.5, "ids": ids, "pos": pos.astype("<f8").tobytes(),
            "vel": vel.astype("<f8").tobytes(), "sigma": sigma.astype("<f8").tobytes(),
            "status": b"\x01\x02"}
    assert unpack(pack_frame(2.5, pack(ids), pos, vel, sigma, status)) == want
