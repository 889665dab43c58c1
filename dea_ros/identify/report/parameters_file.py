"""params.yaml: the fitted parameters, what was identified and how, and a header naming the data and methods."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from ..result import IdentificationResult

__all__ = ["write_parameters"]


def write_parameters(result: IdentificationResult, path: str | Path) -> Path:
    """Fitted parameters as YAML: the MembraneParameters fields under ``membrane:`` (loadable by
    :meth:`MembraneParameters.from_yaml` and every node and command), what was identified and how
    under ``identification:`` (per parameter: status, 95 % interval and the records that determine it;
    sigma_h''(1) "not identified" when the data do not determine it: beta/gamma then carry the free
    fit's value as a representative), and a header naming the data and the methods."""
    path = Path(path)
    exp = result.experiments
    lines = [
        "dea_ros membrane parameters, SI units (m, kg, Pa, Pa s, V/m); fields: see dea_ros.model.parameters,",
        "paper eqs. 1-12, Tables I-II.",
        f"fitted by dea_ros.identify from {exp.folder if exp.folder else 'in-memory data'} ({exp.summary()})",
        f"static fit: {result.options.get('static_method')}, dynamic fit: {result.options.get('dynamic_method')} "
        f"with frequency response by {result.options.get('frequency_method')}, refinement: "
        f"{result.options.get('refine', 'none')}",
    ]
    if result.static is not None and result.static.method == "lsq":
        fitted = ("sigma_h(1), its slope and eps_r" if result.slope_fitted else
                  "sigma_h(1) and eps_r (the slope sigma_h'(1) HELD at the base value: one mass and no step or sine)")
        lines.append(f"identified: {fitted} (and the curvature where the 'identification' "
                     "section says so); beta/gamma are one representative, not individually identifiable")
    if result.curvature_identified is False:
        lines.append("sigma_h''(1): NOT IDENTIFIED by these data; beta/gamma carry a representative value that "
                     "does not steer the other parameters (see 'identification' and report.md)")
    text = "\n".join(f"# {line}" for line in lines) + "\n"
    data = {"membrane": result.parameters.to_dict(), "identification": _plain(result.identification_metadata())}
    text += yaml.safe_dump(data, sort_keys=False)
    path.write_text(text)
    return path


def _plain(obj):
    """YAML-safe copy (floats, lists, strings)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj)
    if isinstance(obj, (np.integer, int)) and not isinstance(obj, bool):
        return int(obj)
    return obj
