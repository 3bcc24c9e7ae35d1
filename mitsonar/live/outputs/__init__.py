"""Where a live head's pings go besides its client (``mitsonar live --foxglove/--mcap/--dds``).

`LiveOutput` is what an output does (``publish(t_ns, vehicle, mount, scan)``, ``close()``);
`LiveOutputs` fans the pings out to several from a thread of its own (`mitsonar.live.outputs.base`);
`open_outputs` opens those the flags ask for. Outputs: `mitsonar.live.outputs.foxglove`
(a Foxglove WebSocket server), `mitsonar.live.outputs.mcapfile` (an MCAP recording),
`mitsonar.live.outputs.dds` (ROS 2 topics over DDS). Their packages (foxglove-sdk, cyclonedds)
are imported only when asked for.
"""
from __future__ import annotations

from mitsonar.live.outputs.base import LiveOutput, LiveOutputs, OutputError

__all__ = ["LiveOutput", "LiveOutputs", "OutputError", "open_outputs"]


def open_outputs(*, foxglove=None, mcap=None, dds=None, out=None, maxsize: int = 8, force=False) -> LiveOutputs:
    """`LiveOutputs` to a Foxglove server on ``127.0.0.1:foxglove`` (a port; None: none), an MCAP
    recording ``mcap`` (a path; an existing file is refused unless ``force``) and ROS 2 topics on
    DDS domain ``dds`` (None: none), sharing one picture of each ping. An output that cannot open raises `OutputError` (one line) after those
    already open are discarded."""
    from mitsonar.live.outputs.pictures import Pictures

    if mcap is not None:
        from mitsonar.live.outputs.mcapfile import check_mcap_path
        check_mcap_path(mcap, force)
    if dds is not None:
        from mitsonar.live.outputs.dds import check_domain
        check_domain(dds)
    pictures = Pictures()
    opened = []
    try:
        if foxglove is not None:
            from mitsonar.live.outputs.foxglove import FoxgloveServer
            opened.append(FoxgloveServer(foxglove, pictures))
        if mcap is not None:
            from mitsonar.live.outputs.mcapfile import McapRecording
            opened.append(McapRecording(mcap, pictures, force=force))
        if dds is not None:
            from mitsonar.live.outputs.dds import DdsOutput
            opened.append(DdsOutput(dds, pictures))
    except BaseException:
        for o in opened:
            getattr(o, "discard", o.close)()
        raise
    return LiveOutputs(opened, maxsize=maxsize, out=out)
