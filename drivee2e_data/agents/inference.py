"""A closed-loop agent's network run on batches of numpy inputs: moved to the agent's device,
run without gradients, the plans `(B, T, 2)` back as float64. On a CUDA device each input shape's
forward is recorded once as a CUDA graph and replayed: a policy server runs every batch at one
shape (`evaluate/policy_server.py`), and a graph launches the network's few hundred small
kernels in one call instead of one Python call each, which bound the served TCP's forward
(docs/benchmarks.md, "Closed loop"). A replay runs the kernels the recording ran, the ones an
eager forward of that shape runs, so the plans are the eager ones (compared on a GPU by
`scripts/dev/graph_parity.py`). `DRIVEE2E_AGENT_CUDA_GRAPHS=0` runs every forward eagerly."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

GRAPHS_VARIABLE = "DRIVEE2E_AGENT_CUDA_GRAPHS"
# eager passes before a recording: cuDNN and cuBLAS make their workspaces and handles on a
# first call, which a recording must not contain
WARMUP_PASSES = 3


@dataclass
class _Recording:
    """One input shape's graph: the tensors it reads (filled before each replay) and the plans
    it writes."""

    graph: torch.cuda.CUDAGraph
    inputs: tuple[torch.Tensor, ...]
    plans: torch.Tensor


class NetworkRunner:
    """`model` (in eval mode, on `device`) as a function of numpy arrays to plans; with
    `graphs` (default: on, unless `GRAPHS_VARIABLE` is 0) and a CUDA device, replayed from a
    CUDA graph per input shape. The model's output is its plans, or a tuple whose first item
    is."""

    def __init__(self, model: nn.Module, device: str, graphs: bool | None = None) -> None:
        self.model, self.device = model, torch.device(device)
        if graphs is None:
            graphs = os.environ.get(GRAPHS_VARIABLE, "1") != "0"
        self.graphs = graphs and self.device.type == "cuda"
        self._recordings: dict[tuple[tuple[int, ...], ...], _Recording] = {}

    @torch.no_grad()
    def plans(self, *arrays: np.ndarray) -> np.ndarray:
        """The model's plans `(B, T, 2)` (float64) for its inputs, each `(B, ...)`."""
        if not self.graphs:
            inputs = [torch.from_numpy(np.ascontiguousarray(a)).to(self.device) for a in arrays]
            return _plans_of(self.model(*inputs)).double().cpu().numpy()
        shape = tuple(a.shape for a in arrays)
        # recorded and replayed with the model's device current and on its streams: a runner on
        # cuda:1 in a process where cuda:0 was current failed every capture (found on a 4-GPU
        # host: each policy server but cuda:0's failed its first batch)
        with torch.cuda.device(self.device):
            recording = self._recordings.get(shape)
            if recording is None:
                recording = self._recordings[shape] = self._record(arrays)
            for target, array in zip(recording.inputs, arrays, strict=True):
                target.copy_(torch.from_numpy(np.ascontiguousarray(array)))
            recording.graph.replay()
            return recording.plans.double().cpu().numpy()

    def _record(self, arrays: tuple[np.ndarray, ...]) -> _Recording:
        """The model's forward for inputs shaped like `arrays`, recorded after warm-up passes on
        a side stream (as torch's CUDA-graph guide asks)."""
        inputs = tuple(torch.from_numpy(np.ascontiguousarray(a)).to(self.device) for a in arrays)
        current = torch.cuda.current_stream(self.device)
        side = torch.cuda.Stream(self.device)
        side.wait_stream(current)
        with torch.cuda.stream(side):
            for _ in range(WARMUP_PASSES):
                self.model(*inputs)
        current.wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        # captured on the side stream, of the model's device: torch's default capture stream is
        # made once a process, on whichever device was current at the first capture
        with torch.cuda.graph(graph, stream=side):
            plans = _plans_of(self.model(*inputs))
        return _Recording(graph, inputs, plans)


def _plans_of(output: torch.Tensor | tuple[torch.Tensor, ...]) -> torch.Tensor:
    return output[0] if isinstance(output, tuple) else output
