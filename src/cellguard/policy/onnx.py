"""ONNX adapter (``onnx:FILE``): a policy exported to ONNX, run by onnxruntime on the CPU.

The model's inputs are fed by name: ``state`` (1, A) the state in the policy's own space,
``time_s`` (1, 1) seconds since the episode began, and any camera measurement by its name
(``part_in_camera`` (1, 3) [m]), each in the element type it declares (float16, float or double;
any other type is refused at load). Its first output is the chunk, floats too, (1, H, A), (H, A) or
(1, A); any other shape is refused (a batch of chunks was flattened into one long chunk). Its content
hash covers the model file and the external-data files it names, which lie in its folder.
Metadata properties the model may carry: ``cellguard.action_names`` (comma-separated),
``cellguard.dt_s`` (step period; without it the source gives ``?dt=``), ``cellguard.action_map`` (an action map, YAML).
"""

from __future__ import annotations

import hashlib
import os
import stat
from pathlib import Path

import numpy as np

from cellguard.embodiment.profile import SOFT_MARGIN
from cellguard.errors import ConfigError
from cellguard.policy.adapter import (InferenceError, MappedPolicy, PolicyInputs, resolve_map, split_options, stated_dt,
                                      step_period)
from cellguard.policy.chunk import MAX_HORIZON

OPTIONS = {"map": "action map YAML file", "dt": "step period [s], overrides the model's"}
TAKES_FILE = True  # onnx:FILE, frozen in a release by its absolute path (cellguard.policy.registry)
_FIXED_INPUTS = ("state", "time_s")
_FEED_TYPES = {"tensor(float16)": np.float16, "tensor(float)": np.float32, "tensor(double)": np.float64}
MAX_MODEL_BYTES = (1 << 31) - 1  # protobuf reads no message of 2 GiB or more; larger weights are external data


class OnnxBackend:
    """An onnxruntime session whose inputs are checked against what a cell can feed it."""

    def __init__(self, path: Path, measurements: tuple[str, ...]):
        try:
            import onnxruntime as ort
        except ImportError:  # pragma: no cover - depends on the environment
            raise ConfigError("policy: onnx: needs onnxruntime; install it with pip install 'cellguard[onnx]'") from None
        path = Path(path)
        size = _model_file(path).st_size
        if size > MAX_MODEL_BYTES:  # refused by its size: reading it whole to hash it took 3.3 GB for a 3 GB file
            raise ConfigError(f"policy: onnx:{path}: {size} bytes; protobuf reads no model file of 2 GiB or more, "
                              f"so a model this large keeps its weights as ONNX external data beside it")
        self._bytes_hash = _content_hash(path)
        self._where = f"onnx:{path}"
        options = ort.SessionOptions()
        options.intra_op_num_threads, options.inter_op_num_threads = 1, 1
        try:
            self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own untyped errors for a bad file
            raise ConfigError(f"policy: onnx:{path}: not a loadable ONNX model ({type(exc).__name__})") from None
        self.inputs = [(i.name, i.shape, i.type) for i in self.session.get_inputs()]
        for name, _, kind in self.inputs:
            if name not in _FIXED_INPUTS and name not in measurements:
                raise ConfigError(f"policy: onnx:{path}: model input {name!r} cannot be fed; inputs a cell "
                                  f"offers: {', '.join(_FIXED_INPUTS + measurements)}")
            if kind not in _FEED_TYPES:  # it loaded, and every call failed at run time
                raise ConfigError(f"policy: onnx:{path}: model input {name!r} is {kind}; the cell's observations are "
                                  f"floats, fed as {', '.join(_FEED_TYPES)}")
        meta = self.session.get_modelmeta().custom_metadata_map
        names = meta.get("cellguard.action_names")
        self.action_names = tuple(names.split(",")) if names else None
        self.embedded_map = meta.get("cellguard.action_map")
        self.dt_s = stated_dt(meta, "cellguard.dt_s", f"policy: onnx:{path}: metadata")
        output = self.session.get_outputs()[0]
        if output.type not in _FEED_TYPES:  # a string or bool chunk failed every call; an int64 one was truncated
            raise ConfigError(f"policy: onnx:{path}: first output {output.name!r} is {output.type}; a chunk is joint "
                              f"targets, floats: {', '.join(_FEED_TYPES)}")
        shape = output.shape
        last = shape[-1] if shape else None
        if not isinstance(last, int):
            raise ConfigError(f"policy: onnx:{path}: first output needs a fixed last dimension (actions), got {shape}")
        if 0 in shape:  # an empty chunk (horizon 0) loaded, and the guard rejected every one at run time
            raise ConfigError(f"policy: onnx:{path}: first output {output.name!r} declares shape {shape}; a chunk "
                              f"needs at least one step of at least one action (no dimension 0)")
        if len(shape) not in (2, 3) or (len(shape) == 3 and isinstance(shape[0], int) and shape[0] != 1):
            raise ConfigError(f"policy: onnx:{path}: first output {output.name!r} declares shape {shape}; a chunk "
                              f"is (1, H, {last}), (H, {last}) or (1, {last})")
        if isinstance(shape[-2], int) and shape[-2] > MAX_HORIZON:  # loaded, and every chunk was rejected at run time
            raise ConfigError(f"policy: onnx:{path}: first output {output.name!r} declares shape {shape}: "
                              f"{shape[-2]} steps; the guard takes a chunk of at most {MAX_HORIZON}")
        self.action_dim = last
        self._output = output.name

    def check_widths(self, widths: dict[str, int], source: str) -> None:
        """Refuse a model whose inputs cannot take what the cell feeds (every call would fail at run time);
        each is fed as (1, width): rank 2, each fixed dimension that size."""
        for name, shape, _ in self.inputs:
            fed = (1, widths[name])
            if len(shape) != 2 or any(isinstance(d, int) and d != n for d, n in zip(shape, fed)):
                raise ConfigError(f"policy: {source}: model input {name!r} has shape {shape}; the cell feeds it "
                                  f"(1, {widths[name]})")

    def infer(self, inputs: PolicyInputs) -> np.ndarray:
        feed = {}
        for name, _, kind in self.inputs:
            if name == "state":
                value = inputs.state
            elif name == "time_s":
                value = np.array([inputs.time_s])
            else:
                value = inputs.measurements[name]
            feed[name] = np.asarray(value, dtype=_FEED_TYPES[kind]).reshape(1, -1)
        out = self.session.run([self._output], feed)[0]
        chunk = out[0] if out.ndim == 3 and out.shape[0] == 1 else out
        if chunk.ndim != 2 or chunk.shape[1] != self.action_dim:
            raise InferenceError(f"policy: {self._where}: first output has shape {out.shape}; a chunk is "
                                 f"(1, H, {self.action_dim}), (H, {self.action_dim}) or (1, {self.action_dim})")
        return chunk

    def reset(self) -> None:
        """Stateless: nothing to clear."""

    def content_hash(self) -> str:
        return self._bytes_hash


def _model_file(path: Path) -> os.stat_result:
    """The stat of ``path``, a regular file; else a ConfigError saying what it is (a folder or a link loop read
    'no such file')."""
    where = f"policy: onnx:{path}"
    try:
        found = path.stat()
    except FileNotFoundError:
        raise ConfigError(f"{where}: {'is a link to nothing' if path.is_symlink() else 'no such file'}") from None
    except OSError as exc:  # a link loop, a folder not searchable
        raise ConfigError(f"{where}: cannot read the model file ({exc.strerror or type(exc).__name__})") from None
    if stat.S_ISDIR(found.st_mode):
        raise ConfigError(f"{where}: is a folder, not a model file")
    if not stat.S_ISREG(found.st_mode):
        kind = "FIFO" if stat.S_ISFIFO(found.st_mode) else "socket" if stat.S_ISSOCK(found.st_mode) else "device"
        raise ConfigError(f"{where}: is a {kind}, not a model file")
    return found


def _content_hash(path: Path) -> str:
    """sha256 of the model file, read in pieces, then of each external-data file it names (sorted; name, size,
    bytes): new weights beside an unchanged .onnx are a new model. A model without external data hashes as its file.

    Only a file holding the bytes ``location`` (the key of every external-data entry) is parsed to list them: a
    model of 2 GiB is not read whole into memory for nothing."""
    digest, tail, names_data = hashlib.sha256(), b"", False
    with path.open("rb") as file:
        while piece := file.read(1 << 20):
            digest.update(piece)
            names_data = names_data or b"location" in tail + piece[:7] or b"location" in piece
            tail = piece[-7:]
    for name in _external_data(path) if names_data else ():
        file = path.parent / name
        digest.update(f"\0{name}\0{file.stat().st_size}\0".encode())
        with file.open("rb") as data:
            hashlib.file_digest(data, lambda: digest)
    return digest.hexdigest()


def _external_data(path: Path) -> list[str]:
    """The external-data files the model names, sorted, each a regular file in the model's folder (onnxruntime
    1.32 refuses one out of it, older ones read it: an unhashed file, or a FIFO that hangs the load). The folder
    is the one the model is named in or the one its file lies in, as onnxruntime takes it: a Hugging Face cache
    links both files from ``snapshots/REV/`` into ``blobs/``."""
    import onnx
    from onnx.external_data_helper import uses_external_data

    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:  # protobuf's DecodeError and onnx's own, untyped
        raise ConfigError(f"policy: onnx:{path}: not a loadable ONNX model ({type(exc).__name__})") from None
    names = sorted({entry.value for tensor in _tensors(model) if uses_external_data(tensor)
                    for entry in tensor.external_data if entry.key == "location"})
    folder, stored = path.parent.resolve(), path.resolve().parent
    for name in names:
        file = (path.parent / name).resolve()
        if not (file.is_relative_to(folder) or file.is_relative_to(stored)) or not file.is_file():
            raise ConfigError(f"policy: onnx:{path}: external data {name!r} is not a file in the model's folder "
                              f"{folder}; a model's weights lie beside it")
    return names


def _tensors(message):
    """Every TensorProto inside ``message``: initializers, sparse ones, attributes, subgraphs, functions."""
    from google.protobuf.message import Message
    from onnx import TensorProto

    for field, value in message.ListFields():
        if field.type != field.TYPE_MESSAGE:
            continue
        for item in (value,) if isinstance(value, Message) else value:
            if isinstance(item, TensorProto):
                yield item
            yield from _tensors(item)


def make_onnx_policy(arg: str, cell, soft_margin: float = SOFT_MARGIN) -> MappedPolicy:
    """``onnx:FILE[?map=MAP.yaml&dt=0.02]`` for ``cell``."""
    target, options = split_options(arg, OPTIONS, "onnx")
    backend = OnnxBackend(Path(target), tuple(cell.observe().measurements))
    source = f"onnx:{target}"
    amap = resolve_map(backend, cell, options.get("map"), source)
    policy = MappedPolicy(backend, amap, cell, source, step_period(backend, options, source), soft_margin=soft_margin)
    observation = cell.observe()
    backend.check_widths({"state": amap.to_policy_state(observation.q, policy.solver).size, "time_s": 1,
                          **{k: np.size(v) for k, v in observation.measurements.items()}}, source)
    return policy
