"""`replay vessel init`: empirical estimates against the published KVLCC2 values (each within the error the
research note states for its formula), an Otter-like twin that loads and runs straight at the owner's speed,
validity warnings, refusals (one line, exit 2) and no overwrite."""
from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from usv_predictor.errors import ConfigError
from usv_predictor.physics.dynamics import CALM, ManoeuvringModel
from usv_predictor.physics.empirical import (
    OwnerData,
    bseries_quadratic,
    estimate_vessel,
    init_vessel,
    kt_bseries,
    render_yaml,
)
from usv_predictor.physics.vessel import RHO_WATER, load_vessel
from usv_predictor.replay import cli

# KVLCC2 L7 model (Yasukawa & Yoshimura 2015 Tables 1-3) and the propeller speed of the HSVA runs
KV_RPM = 613.8  # (rpm) 10.23 rps
KV_D_P = 0.216  # (m)
KV_K0 = 0.2931  # (-)
KV_THRUST = RHO_WATER * (KV_RPM / 60.0) ** 2 * KV_D_P**4 * KV_K0  # (N) bollard thrust of that k0
KVLCC2 = OwnerData(name="kvlcc2_init", layout="rudder_propeller", L_pp=7.0, B=1.27, d=0.455, C_b=0.81,
                   mass_kg=3272.0, x_G=0.244, rudder_area=0.0654, rudder_span=0.345, propeller_diameter=KV_D_P,
                   thrust_points=((KV_RPM, KV_THRUST),), thrust_unit="rpm", rpm_max=900.0)
PUBLISHED = {  # Yasukawa & Yoshimura 2015 -> (value, stated error of the recommended formula as a fraction)
    ("added_mass", "m_x"): (0.022, 0.05), ("added_mass", "m_y"): (0.223, 0.01), ("added_mass", "J_z"): (0.011, 0.02),
    ("hull", "Y_v"): (-0.315, 0.23), ("hull", "Y_r"): (0.083, 0.20), ("hull", "N_v"): (-0.137, 0.02),
    ("hull", "N_r"): (-0.049, 0.07), ("hull", "Y_vvv"): (-1.607, 0.03), ("hull", "Y_vrr"): (-0.391, 0.04),
    ("hull", "X_vvvv"): (0.771, 0.10), ("hull", "N_vvr"): (-0.294, 0.24),
    ("propeller", "t_P"): (0.220, 0.01), ("propeller", "w_P0"): (0.40, 0.11), ("propeller", "k0"): (0.2931, 0.001),
    ("rudder", "t_R"): (0.387, 0.01), ("rudder", "a_H"): (0.312, 0.14), ("rudder", "x_H"): (-0.464, 0.03),
    ("rudder", "l_R"): (-0.710, 0.27), ("rudder", "epsilon"): (1.09, 0.11), ("rudder", "kappa"): (0.50, 0.14),
    ("rudder", "gamma_R_minus"): (0.5175, 0.14), ("rudder", "eta"): (0.626, 0.001),
}
ABSOLUTE = {("hull", "X_vv"): (-0.040, 0.021), ("hull", "X_vr"): (0.002, 0.022)}  # stated as absolute errors


@pytest.fixture(scope="module")
def kvlcc2():
    return estimate_vessel(KVLCC2)


@pytest.mark.parametrize(("key", "published"), list(PUBLISHED.items()), ids=lambda k: str(k))
def test_kvlcc2_estimate_is_within_the_stated_error(kvlcc2, key, published) -> None:
    value, error = published
    estimate = kvlcc2.sections[key[0]][key[1]].value
    relative = (estimate - value) / abs(value)
    assert abs(relative) <= error + 0.01, f"{key}: {estimate:.4f} vs published {value} ({relative:+.1%})"


@pytest.mark.parametrize(("key", "published"), list(ABSOLUTE.items()), ids=lambda k: str(k))
def test_kvlcc2_estimate_within_the_stated_absolute_error(kvlcc2, key, published) -> None:
    value, error = published
    assert abs(kvlcc2.sections[key[0]][key[1]].value - value) <= error


def test_kvlcc2_rudder_lift_and_propeller_curve(kvlcc2) -> None:
    rudder = kvlcc2.sections["rudder"]
    f_alpha = 6.13 * rudder["aspect_ratio"].value / (rudder["aspect_ratio"].value + 2.25)
    assert f_alpha == pytest.approx(2.747, rel=0.005)  # Fujii, published 2.747
    k0, k1, k2 = (kvlcc2.sections["propeller"][k].value for k in ("k0", "k1", "k2"))
    kt = k0 + 0.4 * k1 + 0.16 * k2
    published = 0.2931 - 0.4 * 0.2753 - 0.16 * 0.1385
    assert abs(kt - published) / published <= 0.10  # note sec. 9.2: K_T(0.4) +9 %


def test_kvlcc2_uncalibrated_resistance_is_friction_only_and_says_so(kvlcc2) -> None:
    r0 = kvlcc2.sections["hull"]["R0"]
    assert abs(r0.value - 0.022) / 0.022 <= 0.23  # ITTC-57 x (1 + k) x S x 1.2, published 0.022
    assert "NOT calibrated" in r0.source
    assert any("no --speed/--at" in w for w in kvlcc2.warnings)
    assert not any("outside" in w for w in kvlcc2.warnings)  # KVLCC2 is inside every hull regression's range


def test_bseries_reproduces_the_research_note_fit() -> None:
    assert kt_bseries(1.062, 1.0, 0.70, 4) == pytest.approx(0.0, abs=0.002)  # J(K_T = 0) of B4-70 P/D 1.0
    assert bseries_quadratic(1.0, 0.70, 4) == pytest.approx((0.4572, -0.3053, -0.1316), abs=0.002)
    assert bseries_quadratic(0.8, 0.70, 4) == pytest.approx((0.3555, -0.2980, -0.1480), abs=0.002)


def test_every_value_has_its_provenance_in_the_yaml(kvlcc2) -> None:
    text = render_yaml(kvlcc2)
    for section in ("added_mass", "hull", "propeller", "rudder"):
        for key in kvlcc2.sections[section]:
            line = next(line for line in text.splitlines() if line.strip().startswith(f"{key}:"))
            assert "#" in line and len(line.split("#", 1)[1].strip()) > 3, line
    assert "Clarke et al. 1983" in text
    assert "Zhou et al. 1983" in text
    assert "Kijima 1990" in text


def test_calibrated_resistance_gives_the_known_speed(tmp_path: Path) -> None:
    owner = OwnerData(**{**vars(KVLCC2), "speed_m_s": 1.179, "speed_command": KV_RPM})
    init_vessel(owner, tmp_path / "kv.yaml")
    vessel = load_vessel(tmp_path / "kv.yaml")
    assert ManoeuvringModel(vessel).straight_speed(KV_RPM) == pytest.approx(1.179, rel=1e-4)
    assert "calibrated" in (tmp_path / "kv.yaml").read_text()


OTTER_LIKE = OwnerData(name="otter_like", layout="twin_thrusters", L_pp=2.0, B=1.08, d=0.195, mass_kg=80.0,
                       x_G=0.153, hulls=2, demihull_beam=0.25, thruster_spacing=0.79,
                       thrust_points=((1.0, 119.7), (-1.0, -66.7)), speed_m_s=2.5, speed_command=0.8,
                       engine_time_constant_s=0.1)


def _run_straight(vessel, command: float, seconds: float = 120.0, dt: float = 0.02) -> float:
    """Surge speed after `seconds` from rest at a constant command on both thrusters (RK4)."""
    model = ManoeuvringModel(vessel)
    state = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]

    def f(x):
        return model.derivative(x, command, command, CALM)

    for _ in range(int(seconds / dt)):
        k1 = f(state)
        k2 = f([s + 0.5 * dt * k for s, k in zip(state, k1)])
        k3 = f([s + 0.5 * dt * k for s, k in zip(state, k2)])
        k4 = f([s + dt * k for s, k in zip(state, k3)])
        state = [s + dt / 6.0 * (a + 2 * b + 2 * c + d) for s, a, b, c, d in zip(state, k1, k2, k3, k4)]
    return state[3]


def test_otter_like_twin_loads_and_runs_straight_at_the_given_speed(tmp_path: Path) -> None:
    path = tmp_path / "otter_like.yaml"
    assert cli.main(["vessel", "init", "--name", "otter_like", "--layout", "twin_thrusters", "--lpp", "2",
                     "--beam", "1.08", "--mass", "80", "--draught", "0.195", "--x-g", "0.153", "--hulls", "2",
                     "--demihull-beam", "0.25", "--thruster-spacing", "0.79", "--thrust", "1:119.7",
                     "--thrust=-1:-66.7", "--speed", "2.5", "--at", "0.8", "--engine-time-constant", "0.1",
                     "--output", str(path)]) == 0
    vessel = load_vessel(path)
    assert vessel.hull_model_name == "small_craft"
    assert vessel.layout == "twin_thrusters"
    assert vessel.small_craft.Y_vdot == pytest.approx(-1.5 * 80.0)  # Fossen's Otter rule
    assert vessel.small_craft.cross_flow_cd == pytest.approx(1.0042, abs=0.002)  # as the shipped otter preset
    assert vessel.thrusters.port.reverse_N == pytest.approx(66.7)
    assert _run_straight(vessel, 0.8) == pytest.approx(2.5, rel=0.03)


def test_simulate_runs_the_written_file(tmp_path: Path) -> None:
    path = tmp_path / "otter_like.yaml"
    init_vessel(OTTER_LIKE, path)
    assert cli.main(["simulate", "--vessel", str(path), "--manoeuvre", "turning-circle", "--differential", "0.4",
                     "--throttle", "0.8", "--duration", "20", "--output", str(tmp_path / "sim")]) == 0
    assert (tmp_path / "sim" / "turning_circle_stbd_d0.4_p0.8" / "metadata.yaml").is_file()


def test_a_small_planing_monohull_gets_one_warning_per_range(tmp_path: Path) -> None:
    owner = OwnerData(name="survey", layout="rudder_throttle", L_pp=4.0, B=1.7, d=0.2, mass_kg=350.0,
                      rudder_area=0.05, rudder_span=0.25, propeller_diameter=0.25, thrust_points=((100.0, 900.0),),
                      thrust_unit="throttle", speed_m_s=5.0, speed_command=100.0)
    e = estimate_vessel(owner)
    lines = e.warnings
    assert sum("L/B" in w for w in lines) == 1
    assert sum("B/d" in w for w in lines) == 1
    assert sum("C_b" in w and "outside 0.5-0.85" in w for w in lines) == 1
    assert sum("planing" in w for w in lines) == 1
    assert all("\n" not in w for w in lines)
    result = init_vessel(owner, tmp_path / "survey.yaml")
    assert result["warnings"] == lines
    assert (tmp_path / "survey.yaml").read_text().count("# WARNING:") == len(lines)
    assert load_vessel(tmp_path / "survey.yaml").throttle.forward_N == pytest.approx(900.0)


def test_no_warning_for_a_hull_inside_the_ranges() -> None:
    owner = OwnerData(**{**vars(KVLCC2), "speed_m_s": 1.179, "speed_command": KV_RPM})
    warnings = estimate_vessel(owner).warnings
    assert [w for w in warnings if not w.startswith("wave drift:")] == []
    assert len(warnings) == 1 and "UPPER BOUND" in warnings[0]  # the short-wave asymptote's, always given


BASE = ["vessel", "init", "--name", "b", "--layout", "twin_thrusters", "--lpp", "4", "--beam", "1.6",
        "--draught", "0.25", "--thruster-spacing", "0.9", "--thrust", "1:300"]


@pytest.mark.parametrize(("argv", "fragment"), [
    ([*BASE, "--mass", "400", "--beam", "-1"], "--beam: '-1' is not a finite number > 0"),
    ([a for a in BASE], "required: --mass"),
    ([*BASE[:-2], "--mass", "400"], "needs the datasheet's static thrust"),
    ([*BASE, "--mass", "400", "--speed", "2"], "--speed and --at go together"),
    ([*BASE, "--mass", "400", "--layout", "rudder_propeller"],
     "needs --rudder-area, --rudder-span, --propeller-diameter"),
    ([*BASE, "--mass", "5", ], "gives C_b = 0.003"),
    ([*BASE, "--mass", "400", "--thrust-unit", "pwm"], "beyond full command"),
])
def test_refusals_are_one_line_with_exit_2(tmp_path: Path, capsys, argv, fragment) -> None:
    out = tmp_path / "v.yaml"
    assert cli.main([*argv, "--output", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("replay vessel: error:"), err
    assert fragment in err[0], err
    assert not out.exists()


def test_never_overwrites_without_force(tmp_path: Path, capsys) -> None:
    out = tmp_path / "v.yaml"
    out.write_text("mine\n")
    argv = [*BASE, "--mass", "400", "--output", str(out)]
    assert cli.main(argv) == 2
    assert "exists: not overwritten (use --force" in capsys.readouterr().err
    assert out.read_text() == "mine\n"
    assert cli.main([*argv, "--force"]) == 0
    assert yaml.safe_load(out.read_text())["name"] == "b"
    assert [p.name for p in tmp_path.iterdir()] == ["v.yaml"]  # no temporary file left


def test_library_refuses_inconsistent_data() -> None:
    with pytest.raises(ConfigError, match="--draught or --block-coefficient"):
        OwnerData(name="x", layout="twin_thrusters", L_pp=4.0, B=1.6, mass_kg=400.0, thruster_spacing=1.0,
                  thrust_points=((1.0, 100.0),))
    with pytest.raises(ConfigError, match="--beam"):
        OwnerData(name="x", layout="twin_thrusters", L_pp=4.0, B=math.nan, d=0.2, mass_kg=400.0,
                  thruster_spacing=1.0, thrust_points=((1.0, 100.0),))
