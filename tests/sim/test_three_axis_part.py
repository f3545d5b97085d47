"""The simulated three-axis part (drivers/sim/gyro3.py) in its cube (drivers/sim/cube.py) on
the table, seen through its fixture socket's frames: physics against the truth, orientation,
the operator's turns, the CAL3 registers and the compensated output."""

from __future__ import annotations

import json

import numpy as np
import pytest

from drivers import fixture_protocol as fp
from drivers.orientation import ORIENTATIONS, STANDARD_GRAVITY_MPS2, face_from_accel, up_vector
from drivers.part_codes import ADIS16130
from drivers.protocols import CalibrationRegisters3
from drivers.sim import motion
from drivers.sim.config import CubeConfig, parse_sim_config
from drivers.sim.cube import Cube, resting_attitude
from drivers.sim.gyro3 import PartModel3
from drivers.sim.operator_eyes import OperatorEyes
from drivers.sim.world import World

QUIET = {"arw_deg_per_sqrt_h": 0.0, "bias_instability_deg_per_h": 0.0,
         "rrw_deg_per_h_per_sqrt_h": 0.0}


def _world(three_axis: dict | None = None, quiet: bool = True, **cfg: object) -> World:
    part = {"socket": 1, "serial": "IMU-0001", "three_axis": three_axis or {},
            **(QUIET if quiet else {})}
    # the ideal thermal physics (docs/simulated-bench.md): outputs exact to the model
    raw = {"parts": [part], "table": {"ripple_dps": 0.0},
           "part_physics": {"thermal": {"mode": "ideal"}}, **cfg}
    w = World(parse_sim_config(raw), speed=1.0, lockstep=True)
    for line in ("VOLT 5.0", "CURR 0.5", "OUTP ON"):
        w.supply.handle(line)
    w.advance()
    return w


def _spin(w: World, rate_dps: float, t0: float) -> None:
    sock = w.sockets[1]
    piece = motion.Piece(t0, np.inf, (float(sock._last_angle_deg), rate_dps))
    w.table.profile = motion.Profile((piece,), 0.0)


def _record(w: World, t_end: float) -> fp.ParseResult:
    w.advance_to(t_end)
    return fp.FrameParser().feed(w.sockets[1].produce(t_end))


def _dps(res: fp.ParseResult) -> np.ndarray:
    assert res.rate_code_xyz is not None
    return ADIS16130.rate_code_to_dps(res.rate_code_xyz)


def _mps2(res: fp.ParseResult) -> np.ndarray:
    assert res.accel_code_xyz is not None
    return ADIS16130.accel_code_to_mps2(res.accel_code_xyz)


def test_resting_attitudes_are_rotations_with_the_face_up() -> None:
    for face in ORIENTATIONS:
        r = resting_attitude(face)
        assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)
        assert np.allclose(r @ up_vector(face), [0, 0, 1])


def test_static_output_is_bias_plus_g_sensitivity_times_gravity_on_each_face() -> None:
    w = _world()
    sock = w.sockets[1]
    part = sock.part
    assert isinstance(part, PartModel3)
    th = part.three
    assert fp.FrameParser().feed(sock.handle_line("AXES?", 0.0)).replies == ["OK 3"]
    sock.handle_line("START", 0.0)
    t = 0.0
    for face in ("+z", "-x", "+y"):
        sock.cube.place(face)
        t += 2.0
        res = _record(w, t)
        die = fp.temp_code_to_c(res.temp_code)
        d_t = (die.mean() - 25.0)
        a = STANDARD_GRAVITY_MPS2 * up_vector(face)
        expect = (np.array(th.bias_dps) + np.array(th.bias_temp_coeff_dps_per_c) * d_t
                  + np.asarray(th.g_sensitivity_dps_per_mps2) @ a)
        np.testing.assert_allclose(_dps(res).mean(axis=0), expect, atol=2e-4)
        assert face_from_accel(_mps2(res).mean(axis=0)) == face
        np.testing.assert_allclose(_mps2(res).mean(axis=0), a, atol=0.01)


def test_table_rate_on_a_face_gives_the_matrix_column_and_compensation_undoes_it() -> None:
    w = _world()
    sock = w.sockets[1]
    part = sock.part
    assert isinstance(part, PartModel3)
    sock.cube.place("-y")
    sock.handle_line("ODR 100", 0.0)
    sock.handle_line("START", 0.0)
    _record(w, 1.0)
    _spin(w, 100.0, 1.0)
    res = _record(w, 3.0)
    w_true = 100.0 * up_vector("-y")
    die = fp.temp_code_to_c(res.temp_code).mean()
    th = part.three
    s = np.linalg.inv(np.asarray(th.matrix)) @ np.diag(
        1 + np.asarray(th.scale_temp_coeff_per_c) * (die - 25.0))
    b = np.array(th.bias_dps) + np.array(th.bias_temp_coeff_dps_per_c) * (die - 25.0)
    g = np.asarray(th.g_sensitivity_dps_per_mps2) @ (STANDARD_GRAVITY_MPS2 * up_vector("-y"))
    np.testing.assert_allclose(_dps(res).mean(axis=0), s @ w_true + b + g, atol=5e-4)
    # program the true registers over CAL3, compensation on: the output is the true rate
    regs = th.registers()
    for key, size in fp.CAL3_SIZES.items():
        values = np.ravel(getattr(regs, fp.CAL3_FIELDS[key]))
        assert len(values) == size
        line = f"CAL3 {key}=" + ",".join(f"{v:.12g}" for v in values)
        assert fp.FrameParser().feed(sock.handle_line(line, 3.0)).replies == ["OK"]
    sock.handle_line("COMP 1", 3.0)
    res = _record(w, 5.0)
    assert set((res.status & fp.SampleStatus.COMPENSATED).tolist()) == {
        int(fp.SampleStatus.COMPENSATED)}
    np.testing.assert_allclose(_dps(res).mean(axis=0), w_true, atol=2e-3)


def test_cal3_commands_on_the_wire() -> None:
    w = _world()
    sock = w.sockets[1]

    def ask(line: str) -> str:
        return fp.FrameParser().feed(sock.handle_line(line, 0.0)).replies[0]

    assert ask("CAL3? matrix") == "OK matrix=1.0,0.0,0.0,0.0,1.0,0.0,0.0,0.0,1.0"
    assert ask("CAL3? t0") == "OK t0=25.0"
    assert ask("CAL3 bias=1,2,3 t0=30") == "OK"
    assert ask("CAL3? bias") == "OK bias=1.0,2.0,3.0"
    assert ask("CAL3 bias=1,2").startswith("ERR 1 ")
    assert ask("CAL3 bias=1,2,nan").startswith("ERR 3 ")
    assert ask("CAL3 matrix=0,0,0,0,0,0,0,0,0").startswith("ERR 3 ")
    assert ask("CAL3 wobble=1").startswith("ERR 4 ")
    assert ask("CAL3 bias=9,9,9 wobble=1").startswith("ERR 4 ")
    assert ask("CAL3? bias") == "OK bias=1.0,2.0,3.0"  # all or nothing
    assert ask("CAL?").startswith("ERR 4 ")  # single-axis registers: not on this part
    part = sock.part
    assert isinstance(part, PartModel3)
    assert part.cal3 == CalibrationRegisters3(bias_dps=(1, 2, 3), t0_c=30.0)


def test_a_single_axis_part_answers_axes_1_and_refuses_cal3() -> None:
    w = World(parse_sim_config({"parts": [{"socket": 1, "serial": "S1"}]}), speed=1.0)
    for line in ("VOLT 5.0", "CURR 0.5", "OUTP ON"):
        w.supply.handle(line)
    w.advance()
    sock = w.sockets[1]
    replies = fp.FrameParser().feed(sock.handle_line("AXES?", 0.0)
                                    + sock.handle_line("CAL3? bias", 0.0)).replies
    assert replies[0] == "OK 1" and replies[1].startswith("ERR 4 ")
    assert "cube" not in sock.truth() and "axes" not in sock.truth()


def test_a_turn_takes_seconds_shows_rate_and_ends_on_the_face() -> None:
    cube = Cube(CubeConfig(), seed=0, socket=1)
    turn = cube.on_prompt(10.0, "+X")
    assert turn is not None and turn.to_face == "+x"
    assert 10.6 <= turn.start_s <= 11.5 and 2.0 <= turn.end_s - turn.start_s <= 4.0
    t = np.linspace(turn.start_s, turn.end_s, 2001)
    rate = cube.turn_rate_dps(t)
    assert np.abs(rate).max() > 20.0
    # the gyro's rate integrates to the cube's attitude change (body-frame kinematics)
    att = turn.attitude(t)
    dt = t[1] - t[0]
    for i in (500, 1000, 1500):
        step = att[i].T @ att[i + 1]
        omega = np.array([step[2, 1], step[0, 2], step[1, 0]]) / dt
        np.testing.assert_allclose(np.degrees(omega), 0.5 * (rate[i] + rate[i + 1]), atol=0.05)
    assert cube.face_at(turn.start_s + 0.1) is None and cube.face_at(turn.end_s) == "+x"
    np.testing.assert_allclose(cube.up_in_part(turn.end_s + 1.0)[0], [1, 0, 0], atol=1e-12)
    assert cube.on_prompt(20.0, "+x") is None  # already up
    assert turn.as_dict()["angle_deg"] == pytest.approx(90.0)  # tipped over an edge
    back = cube.on_prompt(20.0, "-x")
    assert back is not None and back.as_dict()["angle_deg"] == pytest.approx(180.0)
    np.testing.assert_allclose(cube.up_in_part(back.end_s)[0], [-1, 0, 0], atol=1e-12)
    # every turn starts from where the previous one left the cube (a continuous attitude)
    np.testing.assert_allclose(back.attitude(np.array([back.start_s]))[0],
                               turn.final_attitude(), atol=1e-12)
    for face in ("+y", "-z", "+z", "-y"):
        nxt = cube.on_prompt(cube.turns[-1].end_s, face)
        assert nxt is not None
        np.testing.assert_allclose(cube.up_in_part(nxt.end_s)[0], up_vector(face), atol=1e-12)


def test_operator_turns_the_named_cubes_on_an_orientation_prompt() -> None:
    w = _world()
    eyes = OperatorEyes(w)
    line = {"kind": "prompt", "message": "Turn socket 1's cube so that face -Z points up",
            "sockets": {"1": "PROMPT"}, "orientation": "-z"}
    eyes.read(json.dumps(line).encode())
    cube = w.sockets[1].cube
    assert [turn.to_face for turn in cube.turns] == ["-z"]
    assert w.sockets[1].hand.moves == []  # the stop fixture's hand is not moved
    w.advance_to(cube.turns[-1].end_s + 0.1)
    assert w.sockets[1].truth()["cube"]["face"] == "-z"
    eyes.read(json.dumps({**line, "orientation": "sideways"}).encode())
    assert len(cube.turns) == 1


def test_truth_exports_the_contract_parameters() -> None:
    given = {"bias_dps": [0.5, -0.25, 1.0], "g_sensitivity_dps_per_mps2": [[0.01, 0, 0],
             [0, 0.02, 0], [0, 0, -0.01]]}
    w = _world(given)
    truth = w.truth()["sockets"]["1"]
    p = truth["parameters"]
    assert p["axes"] == 3 and truth["axes"] == 3
    assert p["bias_dps"] == given["bias_dps"]
    assert p["g_sensitivity_dps_per_mps2"] == given["g_sensitivity_dps_per_mps2"]
    for key in ("bias_temp_coeff_dps_per_c", "bias_supply_coeff_dps_per_v",
                "scale_temp_coeff_per_c", "scale_supply_coeff_per_v"):
        assert len(p[key]) == 3
    m = np.asarray(p["matrix"])
    assert m.shape == (3, 3)
    assert truth["calibration"]["matrix"] == np.eye(3).tolist()
    json.dumps(truth)  # the truth file is JSON


def test_population_spreads_are_realistic_and_deterministic_per_serial() -> None:
    from drivers.sim.config import ThreeAxisSpec
    from drivers.sim.gyro3 import resolve_three_axis

    spec = ThreeAxisSpec()
    ms = np.array([resolve_three_axis(f"IMU-{i}", spec).matrix for i in range(400)])
    off = ms[:, ~np.eye(3, dtype=bool)]
    diag = ms[:, np.eye(3, dtype=bool)]
    assert 0.001 < np.std(off) < 0.01  # misalignment 0.1 to 1 %
    assert 0.005 < np.std(diag) < 0.02  # scale errors about 1 %
    g = np.array([resolve_three_axis(f"IMU-{i}", spec).g_sensitivity_dps_per_mps2
                  for i in range(400)])
    assert 0.002 < np.std(g) < 0.02
    assert resolve_three_axis("IMU-7", spec) == resolve_three_axis("IMU-7", spec)
    with pytest.raises(ValueError, match="matrix"):
        parse_sim_config({"parts": [{"socket": 1, "serial": "X", "three_axis": {
            "matrix": [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]}}]})


def test_noise_is_independent_per_axis_at_the_single_axis_level() -> None:
    w = _world({"accel_noise_mps2": 0.0}, quiet=False)
    sock = w.sockets[1]
    sock.handle_line("ODR 200", 0.0)
    sock.handle_line("START", 0.0)
    res = _record(w, 30.0)
    x = _dps(res) - _dps(res).mean(axis=0)
    arw = w.sockets[1].part.params.arw_deg_per_sqrt_h  # type: ignore[union-attr]
    white = arw / 60.0 * np.sqrt(200.0)
    np.testing.assert_allclose(x.std(axis=0), white, rtol=0.15)
    corr = np.corrcoef(x.T)
    assert np.abs(corr[~np.eye(3, dtype=bool)]).max() < 0.1


def test_six_faces_and_turntable_rates_recover_the_truth_from_the_wire() -> None:
    """The whole chain a three-axis calibration rests on: the operator turns the cube to each
    face on its prompt, the table spins +-r about the up axis, and the decoded frames give back
    b, G (statics) and S = M^-1 D (rate differences) of the part's truth."""
    w = _world()
    sock = w.sockets[1]
    part = sock.part
    assert isinstance(part, PartModel3)
    eyes = OperatorEyes(w)
    sock.handle_line("ODR 100", 0.0)
    sock.handle_line("START", 0.0)
    rate_dps, t = 100.0, 0.0
    static: dict[str, np.ndarray] = {}
    spin: dict[str, np.ndarray] = {}
    temps = []

    def hold(rate: float, seconds: float) -> fp.ParseResult:
        nonlocal t
        _spin(w, rate, t)
        _record(w, t + 0.5)  # settle: the first samples straddle the change
        t += seconds
        res = _record(w, t)
        temps.append(fp.temp_code_to_c(res.temp_code).mean())
        return res

    for face in ORIENTATIONS:
        eyes.read(json.dumps({"kind": "prompt", "sockets": {"1": "PROMPT"},
                              "orientation": face, "message": f"face {face} up"}).encode())
        if sock.cube.turns and sock.cube.turns[-1].to_face == face:
            turn_rate = _dps(_record(w, sock.cube.turns[-1].end_s + 0.5))
            if face != "+z":
                assert np.abs(turn_rate).max() > 10.0  # the gyro saw the cube turn
        t = max(t, w.now_s())
        res = hold(0.0, 4.0)
        assert face_from_accel(_mps2(res).mean(axis=0)) == face
        # the die warms by self-heating meanwhile: take the bias's temperature term out
        d_t_face = fp.temp_code_to_c(res.temp_code).mean() - 25.0
        static[face] = _dps(res).mean(axis=0) - np.asarray(
            part.three.bias_temp_coeff_dps_per_c) * d_t_face
        spin[face] = (_dps(hold(rate_dps, 3.0)).mean(axis=0)
                      - _dps(hold(-rate_dps, 3.0)).mean(axis=0)) / (2 * rate_dps)
        # S e_up = M^-1 e_up (1 + sT_up dT): take the scale's temperature term out too
        axis = "xyz".index(face[1])
        d_t_spin = float(np.mean(temps[-2:])) - 25.0
        spin[face] /= 1 + part.three.scale_temp_coeff_per_c[axis] * d_t_spin
    th = part.three
    g = STANDARD_GRAVITY_MPS2
    bias = np.mean([static[f] for f in ORIENTATIONS], axis=0)
    g_sens = np.column_stack([(static[f"+{a}"] - static[f"-{a}"]) / (2 * g) for a in "xyz"])
    s_est = np.column_stack([(spin[f"+{a}"] - spin[f"-{a}"]) / 2 for a in "xyz"])
    s_true = np.linalg.inv(np.asarray(th.matrix))
    np.testing.assert_allclose(bias, np.asarray(th.bias_dps), atol=1e-4)
    np.testing.assert_allclose(g_sens, np.asarray(th.g_sensitivity_dps_per_mps2), atol=2e-4)
    np.testing.assert_allclose(s_est, s_true, atol=1e-4)


def test_a_slipping_operator_lands_on_another_face_and_a_deaf_one_never_turns() -> None:
    slip = Cube(CubeConfig(wrong_face_probability=1.0), seed=1, socket=2)
    turns = [slip.on_prompt(10.0 * i, "+x") for i in range(1, 6)]
    landed = [t.to_face for t in turns if t is not None]
    assert landed and all(face != "+x" for face in landed)
    assert all(t.asked_face == "+x" for t in turns if t is not None)
    deaf = Cube(CubeConfig(responds=False), seed=1, socket=3)
    assert deaf.on_prompt(1.0, "-z") is None and deaf.prompts_seen == 1
    assert deaf.face_at(100.0) == "+z"


CROSS_C = [[0.0, 0.0, 0.0], [4e-5, 0.0, 0.0], [0.0, 0.0, 0.0]]  # y <- x, per C
CROSS_Q = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 2e-3, 0.0]]  # z <- y, deg/s per (m/s^2)^2


def test_cross_axis_effects_follow_their_formulas() -> None:
    """drivers/sim/cross_axis.py: raw_j += C_jk dT w_k + Q_jk a_k^2 (k != j), the diagonal
    never acting."""
    from drivers.sim.cross_axis import cross_axis_output

    rate = np.array([[100.0, 0.0, 0.0], [0.0, -50.0, 0.0]])
    accel = np.array([[0.0, 9.8, 0.0], [0.0, 0.0, -9.8]])
    d_t = np.array([20.0, -10.0])
    c = np.asarray(CROSS_C) + np.eye(3)  # a diagonal given anyway does nothing
    out = cross_axis_output(rate, accel, d_t, c, np.asarray(CROSS_Q))
    np.testing.assert_allclose(out, [[0.0, 4e-5 * 20.0 * 100.0, 2e-3 * 9.8**2],
                                     [0.0, 0.0, 0.0]])


def test_cross_axis_keys_are_off_diagonal_zero_by_default_and_in_the_truth() -> None:
    from pydantic import ValidationError

    from drivers.sim.config import ThreeAxisSpec
    from drivers.sim.gyro3 import resolve_three_axis

    with pytest.raises(ValidationError, match="diagonal must be 0"):
        ThreeAxisSpec(cross_temp_coeff_per_c=((1e-5, 0, 0), (0, 0, 0), (0, 0, 0)))
    plain = resolve_three_axis("IMU-7", ThreeAxisSpec())
    assert np.count_nonzero(plain.cross_temp_coeff_per_c) == 0
    assert "cross_temp_coeff_per_c" not in plain.as_truth()  # today's truth unchanged
    w = _world({"cross_temp_coeff_per_c": CROSS_C, "g2_cross_dps_per_mps2_sq": CROSS_Q})
    p = w.truth()["sockets"]["1"]["parameters"]
    assert p["cross_temp_coeff_per_c"] == CROSS_C
    assert p["g2_cross_dps_per_mps2_sq"] == CROSS_Q
    assert "cross_temp_coeff_per_c" not in _world().truth()["sockets"]["1"]["parameters"]


def test_the_g_squared_cross_term_shows_on_the_faces_along_its_axis_only() -> None:
    """Static on each face, the same part with and without Q: axis z's output moves by
    Q_zy g^2 on the +-y faces only, the other axes not at all."""
    worlds = (_world(), _world({"g2_cross_dps_per_mps2_sq": CROSS_Q}))
    for w in worlds:
        w.sockets[1].handle_line("START", 0.0)
    g2 = 2e-3 * STANDARD_GRAVITY_MPS2**2
    t = 0.0
    for face in ("+y", "+x", "-y", "-z"):
        t += 2.0
        means = []
        for w in worlds:
            w.sockets[1].cube.place(face)
            means.append(_dps(_record(w, t)).mean(axis=0))
        expect = [0.0, 0.0, g2 if face[1] == "y" else 0.0]
        np.testing.assert_allclose(means[1] - means[0], expect, atol=2e-4, err_msg=face)
