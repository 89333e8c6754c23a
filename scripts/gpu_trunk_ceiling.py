"""What PyTorch itself makes of acting's frozen trunk on this GPU: two ResNet-18s' worth of 224²
images (RGB and depth of `batch` envs) in bf16 and channels-last, eager and replayed from a CUDA
graph (what tch 0.24 cannot reach); and of one round's frames to the GPU (224² RGB u8 and
16-bit depth), from pageable and from pinned memory. Ceilings to read the learner's own figures
against (docs/bench/log.md, "On the H100"); run by scripts/gpu_bench.sh.

    python3 scripts/gpu_trunk_ceiling.py [BATCH ...]
"""

import sys
import time

import torch
import torchvision


def median_ms(fn, reps=7):
    times = []
    for _ in range(reps):
        torch.cuda.synchronize()
        t = time.perf_counter()
        fn()
        torch.cuda.synchronize()
        times.append((time.perf_counter() - t) * 1e3)
    return sorted(times)[len(times) // 2]


def transfer(batch):
    frame = 224 * 224 * 3 + 224 * 224 * 2
    mb = batch * frame / 1e6
    for way, pin in [("pageable", False), ("pinned", True)]:
        x = torch.empty(batch * frame, dtype=torch.uint8, pin_memory=pin)
        x.cuda()
        ms = median_ms(lambda: x.cuda())
        print(f"frames of {batch} envs to the GPU ({mb:.0f} MB), {way}: {ms:.2f} ms ({mb / ms:.1f} GB/s)")


def main():
    torch.backends.cudnn.benchmark = True
    net = torchvision.models.resnet18().cuda().eval().to(torch.bfloat16)
    net = net.to(memory_format=torch.channels_last)
    net.fc = torch.nn.Identity()
    batches = [int(b) for b in sys.argv[1:]] or [256, 512]
    for batch in batches:
        transfer(batch)
    for batch in batches:
        x = torch.rand(2 * batch, 3, 224, 224, device="cuda", dtype=torch.bfloat16)
        x = x.contiguous(memory_format=torch.channels_last)
        with torch.no_grad():
            for _ in range(3):
                net(x)
            eager = median_ms(lambda: net(x))
            g = torch.cuda.CUDAGraph()
            s = torch.cuda.Stream()
            s.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(s):
                net(x)
            torch.cuda.current_stream().wait_stream(s)
            with torch.cuda.graph(g):
                net(x)
            graph = median_ms(g.replay)
        for way, ms in [("eager", eager), ("CUDA graph", graph)]:
            print(
                f"PyTorch {torch.__version__} ResNet-18, {2 * batch} images of 224², bf16 channels-last, "
                f"{way}: {ms:.2f} ms ({ms / batch:.4f} ms a frame of two images)"
            )


if __name__ == "__main__":
    main()
