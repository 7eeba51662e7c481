"""The figures of the nets are drawn from the nets: every box's shape and weight count is
what a forward pass of the real module gives, and the committed pictures in docs/img are
the ones today's code draws (``python -m minid3rqn.diagrams`` redraws them)."""
from pathlib import Path

import numpy as np
import pytest

from minid3rqn import diagrams
from minid3rqn.nets.qnet import QNet, QNetConfig

pytestmark = pytest.mark.docs

ROOT = Path(__file__).resolve().parent.parent


def box_weights(boxes) -> int:
    total = 0
    for lines in boxes:
        for part in (lines if isinstance(lines[0], list) else [lines]):
            total += sum(int(t.split()[0].replace(",", "")) for t in part if t.endswith("weights"))
    return total


@pytest.mark.parametrize("config", [QNetConfig(), QNetConfig.for_variant("ddqn"),
                                    QNetConfig(convs=[[8, 4, 2], [16, 4, 2], [16, 3, 1]],
                                               width=256)])
def test_the_qnet_boxes_are_the_nets_layers(config):
    fig = diagrams.qnet_layers(config)
    net = QNet(config, rng=0)
    assert fig["total"] == sum(p.size for p in net.parameters()) == box_weights(fig["boxes"])
    c, h, w = config.feature_shape()
    assert f"{c} x {h}x{w}" in fig["boxes"][len(config.convs)]          # the last conv
    assert f"{net.n_features} features" in fig["boxes"][len(config.convs) + 1]


def test_the_depth_nets_boxes_are_the_nets_layers():
    disp, pose = diagrams.depth_nets()
    fig = diagrams.dispnet_layers()
    parts = fig["encoder"] + fig["decoder"] + fig["heads"]
    assert fig["total"] == sum(p.size for p in disp.parameters()) == box_weights(parts)
    assert fig["heads"][0][1] == "1 x 32x104" and fig["encoder"][-1][1] == "96 x 2x7"
    fig = diagrams.posenet_layers()
    assert fig["total"] == sum(p.size for p in pose.parameters()) == box_weights(fig["boxes"])


def test_trace_records_every_layer_once_and_leaves_the_net_as_it_was():
    net = QNet(QNetConfig(), rng=0)
    obs = np.zeros((2, 3, 1, 32, 104), np.float32)
    before = net.forward(obs)[0].data
    layers = diagrams.trace(net, obs)
    assert [x.name for x in layers] == ["convs.0", "convs.1", "convs.2", "core", "value",
                                        "advantage"]
    assert all("forward" not in vars(layer) for _, layer in diagrams.layers_of(net))
    assert np.array_equal(net.forward(obs)[0].data, before)


def test_the_committed_figures_are_the_ones_the_code_draws(tmp_path):
    figures = diagrams.figures()
    stale = [name for name, (text, _) in figures.items()
             if diagrams.figure_text(ROOT / "docs" / "img" / name)
             != __import__("json").loads(__import__("json").dumps(text, sort_keys=True))]
    assert not stale, (f"docs/img/{stale} differ from what the code draws: run "
                       f"`python -m minid3rqn.diagrams`")
    written = diagrams.draw_all(tmp_path, only=["net_qnet.png"])
    assert diagrams.figure_text(written[0])["total"] == figures["net_qnet.png"][0]["total"]
