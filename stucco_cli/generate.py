"""`stucco scenes generate`: draw retrieval scenes at random and write one checked scene file per scene
(docs/scene_generator.md)."""
from __future__ import annotations

from pathlib import Path

import click

from stucco_cli.common import Settings, pass_settings, user_errors, writable_dir

#: The spec's knobs and the options that set them (a refused knob is reported under its option's name).
_OPTION_OF = {"min_distractors": "--min-distractors", "max_distractors": "--max-distractors",
              "clutter_density": "--clutter-density", "hiddenness": "--hiddenness",
              "wall_probability": "--wall-probability", "target": "--target", "area_m": "--area",
              "region_margin_m": "--region-margin", "lane_spacing_m": "--lane-spacing"}


def _numbers(option: str, text: str | None, count: int, what: str) -> tuple[float, ...] | None:
    """``count`` comma-separated numbers, or a one-line error naming ``option`` and the text."""
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count:
        raise click.ClickException(f"{option} {text!r}: expected {what}")
    return values


@click.command("generate")
@click.option("--n", "n", type=int, required=True, help="How many scenes.")
@click.option("--seed", "batch_seed", type=int, default=None,
              help="Batch seed (scene i depends only on it and i) [the group's --seed].")
@click.option("--first", type=int, default=0, show_default=True,
              help="Index of the first scene: --first 1000 --n 200 writes GEN_01000 .. GEN_01199.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Directory for the GEN_<index>.toml files.")
@click.option("--min-distractors", type=int, default=2, show_default=True)
@click.option("--max-distractors", type=int, default=6, show_default=True)
@click.option("--clutter-density", type=float, default=0.5, show_default=True,
              help="0: gaps between neighbours up to 8 cm; 1: all 5 mm.")
@click.option("--hiddenness", type=float, default=0.5, show_default=True,
              help="Least share of the target's silhouette the distractors cover, seen from the gripper start.")
@click.option("--wall-probability", type=float, default=0.5, show_default=True,
              help="Chance of each of the tasks' three walls.")
@click.option("--target", type=str, default="mix", show_default=True,
              help="box (cracker box), can (small tomato can), mix (box for even indices, can for odd), any.")
@click.option("--area", type=str, default=None,
              help="X_MIN,Y_MIN,X_MAX,Y_MAX, metres: where the objects go [0.1,-0.45,0.8,0.45].")
@click.option("--region-margin", type=str, default=None,
              help="LOW,HIGH, metres: the target region is the clutter's box grown by a margin drawn in [LOW, HIGH] "
                   "[0.03,0.1].")
@click.option("--lane-spacing", type=float, default=None,
              help="Largest lateral distance between the rummage's poke lanes, m [0.2].")
@click.option("--force-overwrite", is_flag=True, help="Replace existing scene files.")
@pass_settings
def generate_scenes_command(settings: Settings, n: int, batch_seed: int | None, first: int, out_dir: Path,
                            min_distractors: int, max_distractors: int, clutter_density: float, hiddenness: float,
                            wall_probability: float, target: str, area: str | None, region_margin: str | None,
                            lane_spacing: float | None, force_overwrite: bool) -> None:
    """Draw retrieval scenes (a target among distractors, a target region, a generic rummage), check each after
    settling in pybullet, and write OUT/GEN_<index>.toml for each."""
    seed = settings.seed if batch_seed is None else batch_seed
    for option, value, low in (("--n", n, 1), ("--seed", seed, 0), ("--first", first, 0)):
        if value < low:
            raise click.ClickException(f"{option} {value}: expected a whole number >= {low}")
    writable_dir("--out", out_dir)
    from pipeline.scenes.generate import GeneratorSpec, GeneratorSpecError

    knobs: dict = dict(min_distractors=min_distractors, max_distractors=max_distractors,
                       clutter_density=clutter_density, hiddenness=hiddenness, wall_probability=wall_probability,
                       target=target)
    box = _numbers("--area", area, 4, "X_MIN,Y_MIN,X_MAX,Y_MAX in metres")
    if box is not None:
        knobs["area_m"] = (box[:2], box[2:])
    margin = _numbers("--region-margin", region_margin, 2, "LOW,HIGH in metres")
    if margin is not None:
        knobs["region_margin_m"] = margin
    if lane_spacing is not None:
        knobs["lane_spacing_m"] = lane_spacing
    given = {"area_m": area, "region_margin_m": region_margin}
    try:
        spec = GeneratorSpec(**knobs)
    except GeneratorSpecError as e:
        raise click.ClickException(f"{_OPTION_OF[e.knob]} {given.get(e.knob) or e.value}: {e.reason}") from None
    names = [f"GEN_{i:05d}" for i in range(first, first + n)]
    if not force_overwrite:
        for name in names:
            if (out_dir / f"{name}.toml").exists():
                raise click.ClickException(f"{out_dir / f'{name}.toml'}: exists; pass --force-overwrite to replace it")
    from pipeline.atomic import write_text
    from pipeline.scenes.generated_toml import layout_actions
    from pipeline.sim.generate import iter_generated

    with user_errors():
        for g in iter_generated(n, seed, spec=spec, first=first):
            path = write_text(out_dir / f"{g.name}.toml", g.text)
            lay = g.layout
            walls = ", ".join(w.name for w in lay.walls) or "no walls"
            n_actions = len(layout_actions(lay, spec))
            click.echo(f"wrote {path}: {lay.objects[0].name} {lay.placement} {len(lay.objects) - 1} distractors, "
                       f"{lay.hidden:.0%} hidden; {walls}; {n_actions} actions; {g.draws} draw(s), {g.seconds:.2f} s")
