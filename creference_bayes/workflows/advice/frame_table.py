"""The frame's advice as text for the terminal (``creference advise FRAME``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .frame import FrameAdvice

__all__ = ["frame_advice_table"]


def frame_advice_table(advice: FrameAdvice, rows: int = 15) -> str:
    """The advice as text: the present per object, the best ``rows`` candidates, the recommendation."""
    s = advice.settings
    lines = [f"frame advice: {len(advice.objects)} objects; now ({s.hdi_prob:.0%} interval of the distance, "
             f"{'posterior HDI' if advice.width_source == 'posterior' else 'Laplace approximation'}):"]
    order = np.argsort(-advice.share)
    lines.append("  " + "  ".join(f"{advice.objects[i]} {advice.width_m[i]:.2g} m ({100 * advice.share[i]:.0f} %)"
                                  for i in order[:12]) + ("  …" if len(order) > 12 else ""))
    deg = {"pitch": 180 / np.pi, "roll": 180 / np.pi}
    cam = ", ".join(f"{k}{' deg' if k in deg else ''} {v * deg.get(k, 1.0):.3g}" for k, v in advice.camera_sd.items()
                    if v is not None)
    lines += [f"  camera sd: {cam}" if cam else "  camera: fixed", ""]
    head = ("rank", "object", "annotation", "cost s", "its width now → after", "frame gain pts", "pts/min")
    table = []
    index = {o: k for k, o in enumerate(advice.objects)}
    for k, p in enumerate(advice.predictions[:rows], start=1):
        i = index[p.candidate.object]
        table.append((str(k), p.candidate.object, p.candidate.kind, f"{p.candidate.seconds:.0f}",
                      f"{advice.width_m[i]:.3g} → {p.width_m[i]:.3g} m", f"{p.gain_pct:+.2f}", f"{p.gain_per_minute:+.3f}"))
    widths = [max(len(r[c]) for r in table + [head]) for c in range(len(head))]
    for r in [head] + table:
        lines.append("  ".join(c.ljust(w) if j in (1, 2) else c.rjust(w) for j, (c, w) in enumerate(zip(r, widths))))
    if len(advice.predictions) > rows:
        lines.append(f"  … {len(advice.predictions) - rows} more (--out for all)")
    from .inputs import recommendation_line

    lines += ["", recommendation_line(advice.action, advice.reason)]
    lines += [f"note: {n}" for n in advice.notes]
    lines.append(f"({len(advice.predictions)} annotations weighed from the Laplace approximation at the MAP, "
                 f"κ = {advice.curvature:.2f}; {advice.seconds:.2f} s)")
    return "\n".join(lines)
