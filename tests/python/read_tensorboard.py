"""Reads a run's TensorBoard folder with TensorBoard's own event reader and prints what it holds
as one JSON object: {"scalars": {tag: [[step, value], ...]}, "images": {tag: [[step, width,
height], ...]}, "texts": {tag: [[step, text], ...]}}.

    python3 tests/python/read_tensorboard.py runs/X/tb
"""

import json
import sys

from tensorboard.backend.event_processing import event_accumulator as ea


def main() -> None:
    if len(sys.argv) != 2:
        sys.exit("usage: read_tensorboard.py TB_DIR")
    # size_guidance 0: keep every event, not TensorBoard's sample of them
    acc = ea.EventAccumulator(sys.argv[1], size_guidance={ea.SCALARS: 0, ea.IMAGES: 0, ea.TENSORS: 0})
    acc.Reload()
    tags = acc.Tags()
    out = {
        "scalars": {t: [[e.step, e.value] for e in acc.Scalars(t)] for t in tags["scalars"]},
        "images": {t: [[e.step, e.width, e.height] for e in acc.Images(t)] for t in tags["images"]},
        "texts": {
            t: [[e.step, e.tensor_proto.string_val[0].decode()] for e in acc.Tensors(t)]
            for t in tags["tensors"]
            if acc.SummaryMetadata(t).plugin_data.plugin_name == "text"
        },
    }
    json.dump(out, sys.stdout)
    print()


if __name__ == "__main__":
    main()
