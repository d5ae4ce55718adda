"""Convert Unitree's TorchScript G1 walking policy (unitree_rl_gym motion.pt) to motion.npz, without torch.

Run once, at development time (torch is never needed):

    python robots/unitree_g1/policy/convert.py ../shared/unitree_rl_gym_g1/motion.pt robots/unitree_g1/policy/motion.npz

A TorchScript file is a zip: `data.pkl` (the module tree, pickled) and `data/<n>` (raw little-endian
storages). A restricted unpickler rebuilds the module tree with plain Python objects and each tensor as
a numpy array; nothing else can be loaded (any other global in the pickle is an error). The result is
checked against the architecture the archive's own code/ declares (LSTM 47 -> 64, Linear 64 -> 32, ELU,
Linear 32 -> 12) before it is written.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import pickle
import sys
import zipfile
from pathlib import Path

import numpy as np

STORAGE_DTYPES = {"FloatStorage": np.float32, "DoubleStorage": np.float64, "LongStorage": np.int64,
                  "IntStorage": np.int32}
EXPECTED_SHAPES = {
    "lstm_weight_ih": (256, 47), "lstm_weight_hh": (256, 64), "lstm_bias_ih": (256,), "lstm_bias_hh": (256,),
    "lstm_h0": (1, 1, 64), "lstm_c0": (1, 1, 64),
    "actor0_weight": (32, 64), "actor0_bias": (32,), "actor2_weight": (12, 32), "actor2_bias": (12,),
}
EXPECTED_CLASSES = {
    "root": "__torch__.legged_gym.utils.helpers.PolicyExporterLSTM",
    "memory": "__torch__.torch.nn.modules.rnn.LSTM",
    "actor": "__torch__.torch.nn.modules.container.Sequential",
    "actor0": "__torch__.torch.nn.modules.linear.Linear",
    "actor1": "__torch__.torch.nn.modules.activation.ELU",
    "actor2": "__torch__.torch.nn.modules.linear.___torch_mangle_0.Linear",
}


class Module:
    """A TorchScript module instance: its class name and the attributes its BUILD set."""

    class_name = ""
    attrs: dict

    def __setstate__(self, state: dict) -> None:
        self.attrs = dict(state)


class StorageType:
    def __init__(self, name: str) -> None:
        self.dtype = STORAGE_DTYPES[name]


class PolicyUnpickler(pickle.Unpickler):
    """Knows only tensors, storages, module classes and TorchScript's two list helpers."""

    def __init__(self, data: bytes, archive: zipfile.ZipFile, prefix: str) -> None:
        super().__init__(io.BytesIO(data))
        self._archive = archive
        self._prefix = prefix

    def find_class(self, module: str, name: str):  # noqa: ANN201
        if module == "torch._utils" and name == "_rebuild_tensor_v2":
            return _rebuild_tensor_v2
        if module == "torch" and name in STORAGE_DTYPES:
            return StorageType(name)
        if module == "collections" and name == "OrderedDict":
            return dict
        if module == "torch.jit._pickle" and name == "restore_type_tag":
            return lambda value, _type: value
        if module == "torch.jit._pickle" and name == "build_tensorlist":
            return list
        if module.startswith("__torch__."):
            return type(name, (Module,), {"class_name": f"{module}.{name}"})  # NEWOBJ, then BUILD
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}")

    def persistent_load(self, pid):  # noqa: ANN001, ANN201
        kind, storage_type, key, _location, numel = pid
        if kind != "storage":
            raise pickle.UnpicklingError(f"unknown persistent id {kind!r}")
        raw = self._archive.read(f"{self._prefix}/data/{key}")
        array = np.frombuffer(raw, dtype=np.dtype(storage_type.dtype).newbyteorder("<"))
        if array.size != numel:
            raise pickle.UnpicklingError(f"storage {key}: {array.size} elements, the pickle says {numel}")
        return array


def _rebuild_tensor_v2(storage, offset, size, stride, _requires_grad, _hooks, *_rest):  # noqa: ANN001, ANN202
    itemsize = storage.dtype.itemsize
    return np.lib.stride_tricks.as_strided(storage[offset:], shape=tuple(size),
                                           strides=tuple(s * itemsize for s in stride)).copy()


def load_torchscript(path: Path) -> Module:
    with zipfile.ZipFile(path) as archive:
        pkl = next(n for n in archive.namelist() if n.endswith("/data.pkl") and n.count("/") == 1)
        prefix = pkl.split("/")[0]
        return PolicyUnpickler(archive.read(pkl), archive, prefix).load()


def extract(root: Module) -> dict[str, np.ndarray]:
    """The arrays of the LSTM policy, checked against its declared architecture."""
    memory, actor = root.attrs["memory"], root.attrs["actor"]
    layers = {"root": root, "memory": memory, "actor": actor,
              "actor0": actor.attrs["0"], "actor1": actor.attrs["1"], "actor2": actor.attrs["2"]}
    for key, expected in EXPECTED_CLASSES.items():
        if layers[key].class_name != expected:
            raise ValueError(f"{key} is {layers[key].class_name}, expected {expected}")
    arrays = {
        "lstm_weight_ih": memory.attrs["weight_ih_l0"], "lstm_weight_hh": memory.attrs["weight_hh_l0"],
        "lstm_bias_ih": memory.attrs["bias_ih_l0"], "lstm_bias_hh": memory.attrs["bias_hh_l0"],
        "lstm_h0": root.attrs["hidden_state"], "lstm_c0": root.attrs["cell_state"],
        "actor0_weight": layers["actor0"].attrs["weight"], "actor0_bias": layers["actor0"].attrs["bias"],
        "actor2_weight": layers["actor2"].attrs["weight"], "actor2_bias": layers["actor2"].attrs["bias"],
    }
    for key, shape in EXPECTED_SHAPES.items():
        if arrays[key].shape != shape:
            raise ValueError(f"{key} has shape {arrays[key].shape}, expected {shape}")
        if not np.all(np.isfinite(arrays[key])):
            raise ValueError(f"{key} has non-finite values")
    return {key: np.ascontiguousarray(value, dtype=np.float32) for key, value in arrays.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("motion_pt", type=Path)
    parser.add_argument("out_npz", type=Path)
    args = parser.parse_args(argv)
    arrays = extract(load_torchscript(args.motion_pt))
    np.savez(args.out_npz, allow_pickle=False, **arrays)
    digest = hashlib.sha256(args.motion_pt.read_bytes()).hexdigest()
    print(f"{args.motion_pt} (sha256 {digest}) -> {args.out_npz}")
    for key, value in arrays.items():
        print(f"  {key:16s} {value.shape}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
