"""The ``sub_*`` commands (``ipc/PROTOCOL.md`` "Cyclic subscriptions"), on the ROS thread.

The HTTP side has checked what a client sent (medkit's rules and texts); these
guard the wire.  A command that changed the registry is answered once the
change is in the restart state (``when_saved``): a subscription a client was
told about survives a ROS worker killed right after.
"""

from __future__ import annotations

from collections.abc import Callable

from ipc import events
from ipc.protocol import BYTES_MODES

from ..core import args
from ..core.task import Task
from .registry import StreamRegistry

INTERVALS = tuple(events.INTERVALS)


def handlers(registry: StreamRegistry) -> dict[str, Callable[[Task], None]]:
    def entity(a: dict) -> tuple[str, str]:
        return args.string(a, "collection", ("apps", "components", "functions")), args.string(a, "entity_id",
                                                                                            limit=256)

    def duration(a: dict) -> int:
        return args.integer(a, "duration", 1, registry.max_duration)

    def sub_create(task: Task) -> None:
        a = task.args
        collection, entity_id = entity(a)
        mode = args.string(a, "bytes", BYTES_MODES)
        # The client's address (the per-client cap); absent from an older HTTP side or a probe.
        client = args.optional(a, "client", args.string, limit=256) or ""
        kind = a.get("kind", "data")
        resource = args.string(a, "resource")
        if kind == "data":  # a topic, framed by the data family's sampler
            topic, target = args.topic(a), None
        else:               # another family's resource (an execution, a parameter): its target
            topic, target = "", a.get("target")
            kind = args.string(a, "kind")
        result = registry.create(collection, entity_id, resource, topic, mode, args.string(a, "interval", INTERVALS),
                                 duration(a), client, kind, target)
        # Answered once it is in the restart state: it survives a ROS worker killed right after.
        registry.when_saved(lambda: task.reply(result))

    def sub_list(task: Task) -> None:
        task.reply({"items": registry.listing(*entity(task.args))})

    def sub_get(task: Task) -> None:
        task.reply(registry.get(*entity(task.args), args.string(task.args, "id", limit=64)).wire())

    def sub_update(task: Task) -> None:
        a = task.args
        interval = args.optional(a, "interval", args.string, INTERVALS)
        seconds = duration(a) if a.get("duration") is not None else None
        result = registry.update(*entity(a), args.string(a, "id", limit=64), interval, seconds)
        registry.when_saved(lambda: task.reply(result))

    def sub_delete(task: Task) -> None:
        registry.delete(*entity(task.args), args.string(task.args, "id", limit=64))
        registry.when_saved(lambda: task.reply({}))

    return {"sub_create": sub_create, "sub_list": sub_list, "sub_get": sub_get, "sub_update": sub_update,
            "sub_delete": sub_delete}
