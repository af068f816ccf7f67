"""What a tuning run found, and the parameter file it leaves for ``run --params``."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from attitude_sil.core.sim.paramfile import node_key
from attitude_sil.core.sim.params import spec_for

from .spec import TuningSpec, decode

__all__ = ["TuningResult", "parameter_values", "write_best_yaml"]


@dataclass
class TuningResult:
    """What a tuning run found."""

    best_x: np.ndarray
    best_cost: np.ndarray
    best_params: dict
    generations: list = field(default_factory=list)
    evaluations: int = 0
    front: list = field(default_factory=list)
    interrupted: bool = False


def parameter_values(params: dict[str, np.ndarray], i: int) -> dict:
    """Row ``i`` of decoded controller parameters as ROS values: ints for integer parameters, floats otherwise;
    a list for a list parameter, one number for a scalar one (``params[name]`` then (P,)).

    ``final_time`` (a searched episode length, not a parameter) is left out.
    """
    out = {}
    for name, arr in params.items():
        if name == "final_time":
            continue
        kind = spec_for("controller", name).kind
        number = (lambda v: int(round(v))) if kind.startswith("integer") else float
        out[name] = [number(v) for v in arr[i]] if kind.endswith("array") else number(arr[i])
    return out


def write_best_yaml(spec: TuningSpec, x: np.ndarray, path: Path) -> dict:
    """The winning controller parameters as a ready-to-use ROS 2 parameter file.

    Its section is ``/**/controller``, so it applies to a controller under any
    namespace (``--params-file``, ``run --params``, ``param load``).
    """
    params, _ = decode(spec, x[None])
    values = {"controller_type": spec.controller, **parameter_values(params, 0)}
    path.write_text(f"# best of tuning run {spec.name} ({spec.path.name})\n" +
                    yaml.safe_dump({node_key("controller"): {"ros__parameters": values}}, sort_keys=False))
    return values
