"""The ``cso-runtime`` command line (typer). Each command is a thin wrapper over library code."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

app = typer.Typer(
    name="cso-runtime",
    help="Active scene mapping with CSO: evaluate, train, and run the Zenoh services.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root(verbose: bool = typer.Option(False, "--verbose", "-v", help="Debug logging")) -> None:
    """Active scene mapping with CSO (ACM MM 2024) on a LIMO robot: eval, train, and the Zenoh runtime."""
    import logging  # noqa: PLC0415

    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")


@app.command("eval")
def eval_command(
    method: str = typer.Option("greedy-dist", "--method", help="Comma-separated methods: greedy-dist,greedy-info,utility,random,cso,..."),
    maps: str = typer.Option("builtin", "--maps", help="Folder of PNG plans, one PNG, 'builtin', or generated:SCALE:N:SEED"),
    limit: Optional[int] = typer.Option(None, "--limit", help="Use at most N scenes"),
    out: Path = typer.Option(Path("results/eval"), "--out", help="Output folder"),
    m_per_px: float = typer.Option(0.1, "--m-per-px", help="Metres per pixel for PNG plans (0.1 super large, 0.05 large)"),
    seed: int = typer.Option(0, "--seed", help="Episode seed (random policy, sensor noise)"),
    max_steps: int = typer.Option(3000, "--max-steps", help="Step limit per episode (one step = 0.25 s)"),
    lidar_fov: float = typer.Option(180.0, "--lidar-fov", help="LiDAR field of view in degrees: 180 (LIMO) or 360"),
    sensor: str = typer.Option("lidar", "--sensor", help="Sensor preset: lidar or depth"),
    workers: int = typer.Option(1, "--workers", help="Parallel worker processes"),
    sim: str = typer.Option("2d", "--sim", help="Simulator: 2d (fast kinematic) or mujoco (physics)"),
    config: Optional[Path] = typer.Option(None, "--config", help="YAML with exploration parameters (see configs/eval.yaml)"),
) -> None:
    """Run exploration episodes and write the paper's Table 1 metrics, curves and trajectory plots."""
    from cso_runtime.evaluation import EvalRequest, run_eval_cli  # noqa: PLC0415 - keep CLI start fast

    request = EvalRequest(
        methods=[m.strip() for m in method.split(",") if m.strip()],
        maps=maps,
        limit=limit,
        out_dir=out,
        m_per_px=m_per_px,
        seed=seed,
        max_steps=max_steps,
        lidar_fov_deg=lidar_fov,
        sensor=sensor,
        workers=workers,
        sim=sim,
        config_path=config,
    )
    raise typer.Exit(run_eval_cli(request))


# Further commands (service, up, status, down, train, record, replay) register below.


def main() -> None:
    app()


if __name__ == "__main__":
    main()
