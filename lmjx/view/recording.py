"""Reading back what a viser server sends: a scene recording (viser's `.viser` format, the
bytes of `ViserServer.get_scene_serializer().serialize()`, which the HTML export embeds)
decoded into its messages, with their arrays.  What a browser receives, checkable without
a browser: the nodes, their kinds and their data."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass
class SceneMessage:
    time: float  # [s] into the recording
    type: str  # viser's message type, e.g. "MeshMessage", "BatchedMeshesMessage"
    fields: dict[str, Any]  # its fields; arrays as flat numpy arrays of their dtype

    @property
    def name(self) -> str | None:
        return self.fields.get("name")

    def array(self, *path: str) -> np.ndarray:
        """The array at fields[path[0]][path[1]]...; flat (the client knows its shape)."""
        v: Any = self.fields
        for k in path:
            v = v[k]
        return np.asarray(v)


def decode_recording(data: bytes) -> tuple[float, list[SceneMessage]]:
    """A `.viser` recording's duration [s] and messages, in order."""
    import msgspec
    import zstandard

    inner_size = int.from_bytes(data[:8], "little")
    inner = zstandard.ZstdDecompressor().decompress(data[8:], max_output_size=inner_size)
    n = int.from_bytes(inner[:8], "little")
    head = msgspec.msgpack.decode(inner[8 : 8 + n])
    buffers, at = [], 8 + n
    for length in head["binaryBufferLengths"]:
        at += (8 - at % 8) % 8
        buffers.append(inner[at : at + length])
        at += length

    def restore(v: Any) -> Any:
        if isinstance(v, dict):
            if "__binary_index" in v and "dtype" in v:
                return np.frombuffer(buffers[v["__binary_index"]], dtype=np.dtype(v["dtype"]))
            return {k: restore(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [restore(x) for x in v]
        return v

    messages = [SceneMessage(float(t), m["type"], restore(m)) for t, m in head["messages"]]
    return float(head["durationSeconds"]), messages


UPDATES = {
    "SetPositionMessage": "position",
    "SetOrientationMessage": "wxyz",
    "SetSceneNodeVisibilityMessage": "visible",
}


def latest_nodes(messages: list[SceneMessage]) -> dict[str, SceneMessage]:
    """The scene's nodes as the messages leave them: per name, the message that added it,
    its fields completed with its latest `position`, `wxyz` and `visible` (their defaults
    where never set); nodes removed after are left out."""
    nodes: dict[str, SceneMessage] = {}
    for m in messages:
        if m.name is None:
            continue
        if m.type == "RemoveSceneNodeMessage":
            nodes.pop(m.name, None)
        elif m.type in UPDATES:
            if m.name in nodes:
                key = UPDATES[m.type]
                nodes[m.name].fields[key] = m.fields[key]
        elif "props" in m.fields:
            fields = {"position": (0.0, 0.0, 0.0), "wxyz": (1.0, 0.0, 0.0, 0.0), "visible": True, **m.fields}
            nodes[m.name] = SceneMessage(m.time, m.type, fields)
    return nodes
