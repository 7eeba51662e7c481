"""The ``reproduce`` pipeline end to end, with every budget at its smoke size."""
import json

from minid3rqn.rl.reproduce import FAMILY, TRANSFER, reproduce


def test_reproduce_pipeline_smoke(tmp_path):
    res = reproduce(out=tmp_path, budget={"smoke": True, "flights": 4}, workers=1)
    depth = tmp_path / "depth"
    for name in ["basic", "basic_finetuned", "basic_long", *TRANSFER]:
        assert (depth / name / "model.npz").exists(), name
    for sc in TRANSFER:                # the shipped recipe: from basic's last DispNet
        command = json.loads((depth / sc / "results.json").read_text())["command"]
        assert f"--init-from {depth / 'basic_long' / 'model.npz'}" in command, command
        assert "--full-res" in command and "--late-turns 0.5" in command, command
    agents = sorted(p.name for p in (tmp_path / "agent").iterdir())
    assert len(agents) == 2 * len(FAMILY)               # each trained, then fine-tuned
    assert sum(a.endswith("_finetuned") for a in agents) == len(FAMILY)
    assert len(res["table5"]) == 4 + len(FAMILY)        # 4 baselines + the family
    assert len(res["table6"]) == 5 * len(TRANSFER)
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["table5"] == res["table5"]
    assert "Table 6" in (tmp_path / "results.md").read_text()
