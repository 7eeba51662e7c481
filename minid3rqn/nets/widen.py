"""Ours, not the paper's: growing a trained recurrent Q-net's LSTM without changing
what it computes (used by ``distil --set init_widen=true``; docs/d3rqn.md section 12).
"""
from __future__ import annotations

import numpy as np


def widen_recurrent_state(old: dict, fresh: dict) -> dict:
    """Put a recurrent QNet's weights (``old``, LSTM of H0 units) into a net of the same
    torso with a wider LSTM (``fresh``: that net's own initial ``state_dict``, H >= H0
    units), so that the wider net computes exactly the old net's Q-values (ours).

    For each of the four gate blocks the first H0 rows are the old rows; the old units
    read nothing from the new ones (those columns of ``weight_hh`` are zero), and the
    heads read nothing from them (their columns in ``value``/``advantage``/``q_head`` are
    zero). The new units keep ``fresh``'s random weights: they run from the start, and
    only their path to the heads is closed; the first gradient steps open it. So the
    wider net starts where the old one ended and has more room to fit (Net2Net's
    function-preserving growth, Chen et al. 2016, in its simplest form).
    """
    def shape_of(state, key, who):
        if key not in state:
            raise ValueError(f"widen_recurrent_state: {who} has no {key!r}: only a recurrent "
                             f"QNet (DDRQN, D3RQN) can be widened")
        return state[key].shape
    H0 = shape_of(old, "core.weight_hh", "the old net")[1]
    H = shape_of(fresh, "core.weight_hh", "the wider net")[1]
    if H < H0:
        raise ValueError(f"widen_recurrent_state: the new LSTM must be at least as wide as "
                         f"the old one ({H0} units); got {H}")
    if set(old) != set(fresh):
        raise ValueError(f"widen_recurrent_state: the nets differ in their layers: "
                         f"{sorted(set(old) ^ set(fresh))}")
    out = {k: np.array(v, copy=True) for k, v in fresh.items()}
    for k in old:
        if not (k.startswith("core.") or k.split(".")[0] in ("value", "advantage", "q_head")):
            if old[k].shape != fresh[k].shape:
                raise ValueError(f"widen_recurrent_state: only the LSTM may be wider; {k} is "
                                 f"{old[k].shape} in the old net and {fresh[k].shape} in the new")
            out[k] = old[k].astype(out[k].dtype)
    if old["core.weight_ih"].shape[1] != fresh["core.weight_ih"].shape[1]:
        raise ValueError(f"widen_recurrent_state: the LSTM's input differs "
                         f"({old['core.weight_ih'].shape[1]} features in the old net, "
                         f"{fresh['core.weight_ih'].shape[1]} in the new)")
    for gate in range(4):
        new_rows = slice(gate * H, gate * H + H0)
        old_rows = slice(gate * H0, (gate + 1) * H0)
        out["core.weight_ih"][new_rows] = old["core.weight_ih"][old_rows]
        out["core.bias"][new_rows] = old["core.bias"][old_rows]
        out["core.weight_hh"][new_rows, :H0] = old["core.weight_hh"][old_rows]
        out["core.weight_hh"][new_rows, H0:] = 0.0
    for head in ("value", "advantage", "q_head"):
        if f"{head}.weight" in old:
            out[f"{head}.weight"][:, :H0] = old[f"{head}.weight"]
            out[f"{head}.weight"][:, H0:] = 0.0
            out[f"{head}.bias"][...] = old[f"{head}.bias"]
    return out
