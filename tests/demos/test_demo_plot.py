"""The wall demo's plot (issue 36): an x where a case collided, a colour per case that is not the wall's red,
and a caption that explains the lines' shape; the collision time comes from the simulator's contact flag."""

from __future__ import annotations

from matplotlib.colors import to_rgb

from demos.report import SURFACE_COLOUR, figure
from demos.scoring import Window, distance_metrics
from secuav_common.scenario import load_scenario


def _truth(t: float, north: float, collided: bool = False) -> tuple[float, dict[str, object]]:
    return t, {"pos_ned_m": [north, 0.0, -2.5], "collided": collided}


def test_the_collision_time_is_the_simulators_first_contact_from_the_onset() -> None:
    scenario = load_scenario("wall_hover")  # the wall 5 m north: 2.5 m away at north 2.5
    window = Window(start_s=100.0, end_s=140.0, hold_s=95.0)
    truth = [_truth(100.0, 2.5), _truth(120.0, 4.0), _truth(131.5, 4.95, True), _truth(135.0, 4.95, True)]
    hit = distance_metrics(scenario, truth, [], [], window)
    assert hit["collided"] is True and hit["collided_at_s"] == 31.5
    clean = distance_metrics(scenario, truth[:2], [], [], window)
    assert clean["collided"] is False and clean["collided_at_s"] is None


def test_the_plot_marks_the_collision_and_keeps_secure_on_apart_from_the_wall() -> None:
    def case(name: str, hit: float | None) -> dict[str, object]:
        truth = [(t / 2, 2.5 - (t / 2 - 20) * 0.2 if hit and t / 2 > 20 else 2.5) for t in range(0, 80)]
        return {"case": name, "collided_at_s": hit, "series": {"truth": truth, "seen": truth}}

    results = [case("attack-off_secure-off", None), case("attack-off_secure-on", None),
               case("attack-on_secure-off", 32.0), case("attack-on_secure-on", None)]  # fmt: skip
    fig = figure("wall-hover", results)
    truth_ax = fig.axes[0]
    marks = [ln for ln in truth_ax.get_lines() if ln.get_marker() == "X"]
    assert len(marks) == 1 and list(marks[0].get_xdata()) == [32.0]
    assert abs(float(marks[0].get_ydata()[0]) - (2.5 - 12 * 0.2)) < 1e-9  # on the case's own true line
    assert "collision" in truth_ax.get_legend_handles_labels()[1]
    wall = to_rgb(SURFACE_COLOUR)
    colours = {ln.get_label(): to_rgb(ln.get_color()) for ln in truth_ax.get_lines() if ln.get_marker() != "X"}
    assert colours["wall"] == wall
    for label in ("attack-on, secure-on", "attack-off, secure-on"):
        assert sum(abs(a - b) for a, b in zip(colours[label], wall, strict=True)) > 0.5, (label, colours[label])
    assert len({colours[r["case"].replace("_", ", ")] for r in results}) == 4  # type: ignore[attr-defined]
    caption = " ".join(t.get_text() for t in fig.texts)
    assert "touched the wall" in caption and "sonar" in caption
