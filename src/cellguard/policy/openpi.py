"""openpi adapter (``openpi:ws://HOST:PORT``): a remote policy over openpi's websocket protocol.

On connect the server sends its metadata; each request is an observation dict, each reply a
dict with ``actions`` (H, A) and timings, all msgpack with numpy arrays (``cellguard.policy.wire``,
never pickle). Unlike the reference client this one has a receive timeout, reconnects a bounded
number of times, and sends ``Authorization: Api-Key ...`` when a key is given (read from an
environment variable named in the spec, never from the scenario file).

Observation keys sent: ``observation/state`` (A,) float32 in the policy's space (through the
action map), ``observation/time_s`` (1,) since the episode began, ``observation/<measurement>``
for each camera measurement, and ``prompt``.
"""

from __future__ import annotations

import contextlib
import os
from urllib.parse import urlsplit

import numpy as np

from cellguard.embodiment.profile import SOFT_MARGIN
from cellguard.errors import ConfigError
from cellguard.policy.adapter import (DT_RANGE_S, TIMEOUT_RANGE_S, InferenceError, MappedPolicy, PolicyInputs,
                                      option_float, resolve_map, split_options, stated_dt, step_period)
from cellguard.policy.metadata_hash import metadata_sha256
from cellguard.policy.wire import WireError, packb, unpackb

OPTIONS = {"map": "action map YAML file", "dt": "step period [s]", "timeout": "receive timeout [s]",
           "api_key_env": "environment variable holding the API key", "prompt": "task text sent as prompt",
           "retries": "reconnect attempts per call"}
TAKES_FILE = False  # openpi:ws://HOST:PORT, an address (cellguard.policy.registry)
MAX_MESSAGE = 8 << 20  # [bytes] largest message accepted; a reply of 100 steps x 64 actions is 26 kB
MAX_ACTION_DIM = 256


class OpenpiBackend:
    """A websocket connection to an openpi policy server, re-opened when it breaks."""

    def __init__(self, uri: str, api_key: str | None, timeout_s: float, retries: int):
        try:
            import websockets.sync.client  # noqa: F401
        except ImportError:  # pragma: no cover - depends on the environment
            raise ConfigError("policy: openpi: needs websockets and msgpack; pip install 'cellguard[openpi]'") from None
        check_address(uri)
        self.uri, self.timeout_s, self.retries = uri, timeout_s, retries
        self._headers = {"Authorization": f"Api-Key {api_key}"} if api_key else None
        self._ws = None
        self.reconnects = 0
        try:
            self.metadata = self._connect()
        except InferenceError as exc:
            raise ConfigError(str(exc)) from None
        names = self.metadata.get("action_names")
        self.action_names = tuple(str(n) for n in names) if isinstance(names, (list, tuple)) else None
        dim = self.metadata.get("action_dim", len(self.action_names) if self.action_names else None)
        if dim is None:
            raise ConfigError(f"policy: openpi:{uri}: the server's metadata gives no action_dim or action_names; "
                              f"metadata keys: {', '.join(map(str, self.metadata)) or 'none'}")
        if isinstance(dim, bool) or not isinstance(dim, int) or not 0 < dim <= MAX_ACTION_DIM:
            raise ConfigError(f"policy: openpi:{uri}: the server's metadata action_dim {dim!r:.40} is not an "
                              f"integer in 1..{MAX_ACTION_DIM}")
        self.action_dim = dim
        self.embedded_map = None
        # openpi's own servers send no dt_s: the source gives ?dt=
        self.dt_s = stated_dt(self.metadata, "dt_s", f"policy: openpi:{uri}: server metadata")
        self._hash = metadata_sha256(uri, self.metadata)  # at connect: metadata it cannot hash is refused before a run

    def _connect(self) -> dict:
        from websockets.exceptions import InvalidHandshake, WebSocketException
        from websockets.sync.client import connect

        self.close()
        try:
            self._stack = contextlib.ExitStack()  # websockets >= 17 wants connect() used as a context manager
            self._ws = self._stack.enter_context(connect(
                self.uri, additional_headers=self._headers, compression=None, max_size=MAX_MESSAGE,
                open_timeout=self.timeout_s, close_timeout=self.timeout_s))
            metadata = unpackb(self._ws.recv(timeout=self.timeout_s))
        except (OSError, TimeoutError, InvalidHandshake, WebSocketException, WireError) as exc:
            self.close()
            raise InferenceError(f"policy: openpi:{self.uri}: cannot connect ({type(exc).__name__}: {exc})") from None
        if not isinstance(metadata, dict):
            raise InferenceError(f"policy: openpi:{self.uri}: server metadata is not a mapping")
        return metadata

    def infer(self, inputs: PolicyInputs) -> np.ndarray:
        obs = {"observation/state": np.asarray(inputs.state, dtype=np.float32),
               "observation/time_s": np.array([inputs.time_s]), "prompt": inputs.task}
        for name, value in inputs.measurements.items():
            obs[f"observation/{name}"] = np.asarray(value, dtype=np.float32)
        message = packb(obs)
        last = None
        for _ in range(self.retries + 1):
            try:
                return self._exchange(message)
            except InferenceError as exc:
                last = exc
                self.close()  # a late reply must never be taken as the answer to the next request
        raise last

    def _exchange(self, message: bytes) -> np.ndarray:
        from websockets.exceptions import ConnectionClosed, WebSocketException

        if self._ws is None:
            self._connect()
            self.reconnects += 1
        try:
            self._ws.send(message)
            reply = self._ws.recv(timeout=self.timeout_s)
        except TimeoutError:
            raise InferenceError(f"policy: openpi:{self.uri}: no reply within {self.timeout_s} s") from None
        except ConnectionClosed as exc:
            raise InferenceError(f"policy: openpi:{self.uri}: {closed_why(exc)}") from None
        except (OSError, WebSocketException) as exc:
            raise InferenceError(f"policy: openpi:{self.uri}: connection lost ({type(exc).__name__})") from None
        return decode_reply(reply, self.uri)

    def reset(self) -> None:
        """The protocol has no reset message; the server's policy keeps no episode state here."""

    def content_hash(self) -> str:
        return self._hash

    def close(self) -> None:
        if self._ws is not None:
            self._ws = None
            self._stack.close()


def check_address(uri: str) -> None:
    """Refuse an address ``connect`` cannot use, before anything runs: it raised a bare ValueError (a bracket
    left open, a port past 65535) and took port 0 for the scheme's default."""
    from websockets.exceptions import InvalidURI
    from websockets.uri import parse_uri

    where, expected = f"policy: openpi:{uri}", "expected ws://HOST:PORT or wss://HOST:PORT"
    if not uri.startswith(("ws://", "wss://")):
        raise ConfigError(f"{where}: {expected}")
    try:
        port = urlsplit(uri).port
        parse_uri(uri)
    except (ValueError, InvalidURI) as exc:
        why = str(exc).removeprefix(f"{uri} isn't a valid URI: ")
        raise ConfigError(f"{where}: not a valid address ({why}); {expected}") from None
    if port == 0:
        raise ConfigError(f"{where}: port 0 cannot be connected to; a port is 1 to 65535")


def closed_why(exc) -> str:
    """Why the connection closed, with its close code: a reply over MAX_MESSAGE read as a lost connection."""
    if exc.sent is not None and exc.sent.code == 1009:  # we closed it: the reply was over max_size
        return (f"reply over the limit of {MAX_MESSAGE} bytes ({MAX_MESSAGE >> 20} MiB); closed with 1009 "
                f"(message too big)")
    return f"connection lost ({type(exc).__name__}: {exc})"


def decode_reply(reply: bytes | str, uri: str) -> np.ndarray:
    """The ``actions`` array of one reply; a server error (text) or a malformed reply is an InferenceError."""
    if isinstance(reply, str):
        first = reply.strip().splitlines()[-1] if reply.strip() else "empty"
        raise InferenceError(f"policy: openpi:{uri}: server error: {first[:200]}")
    try:
        decoded = unpackb(reply, MAX_MESSAGE)
    except WireError as exc:
        raise InferenceError(f"policy: openpi:{uri}: bad reply ({exc})") from None
    actions = decoded.get("actions") if isinstance(decoded, dict) else None
    if not isinstance(actions, np.ndarray) or actions.ndim not in (1, 2):
        raise InferenceError(f"policy: openpi:{uri}: reply has no 'actions' array of numbers, shape (H, A)")
    if actions.dtype.kind != "f":  # an int64 chunk (truncated degrees and mm) ran, clamped, with nothing said
        raise InferenceError(f"policy: openpi:{uri}: reply's 'actions' are {actions.dtype}; a chunk is joint "
                             f"targets, floats (float16, float32 or float64)")
    return actions


def make_openpi_policy(arg: str, cell, soft_margin: float = SOFT_MARGIN) -> MappedPolicy:
    """``openpi:ws://HOST:PORT?dt=0.0667[&map=FILE&timeout=1&api_key_env=VAR&prompt=...&retries=1]`` (``dt`` unless
    the server's metadata gives ``dt_s``)."""
    target, options = split_options(arg, OPTIONS, "openpi")
    key = None
    if "api_key_env" in options:
        key = os.environ.get(options["api_key_env"])
        if not key:
            raise ConfigError(f"policy: openpi: api_key_env: environment variable {options['api_key_env']!r} is not set")
    written = options.get("retries", "1")
    if not (written.isascii() and written.isdigit()):  # int() read '٣' as 3, which failed only on connecting
        raise ConfigError(f"policy: openpi: option retries={written!r} is not an integer (ASCII digits 0-9)")
    digits = written.lstrip("0") or "0"  # int() refuses over 4300 digits, leading zeros too
    if len(digits) > 1 or int(digits) > 5:
        raise ConfigError(f"policy: openpi: option retries must be in [0, 5], got {digits[:20]}"
                          f"{'...' if len(digits) > 20 else ''}")
    retries = int(digits)
    if "dt" in options:  # checked before connecting: with the server down, a bad ?dt= read as its absence
        option_float(options, "dt", 0.0, "openpi", DT_RANGE_S)
    backend = OpenpiBackend(target, key, option_float(options, "timeout", 2.0, "openpi", TIMEOUT_RANGE_S), retries)
    source = f"openpi:{target}"
    amap = resolve_map(backend, cell, options.get("map"), source)
    dt = step_period(backend, options, source)
    return MappedPolicy(backend, amap, cell, source, dt, task=options.get("prompt", ""), soft_margin=soft_margin)
