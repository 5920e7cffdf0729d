"""The publisher's queue, sized from the cell config, as the daemon binds it (a real
outlet process and socket).

(The configuration models' in-process tests: tests/unit/test_config_models.py.)
"""

from __future__ import annotations


def test_the_publisher_keeps_queue_s_of_its_message_rate_for_a_slow_subscriber(tmp_path):
    """Not 10,000 messages (15 minutes of the stream, +12.6 MB over an 8-hour soak): queue_s
    of what it sends, a batch per pressure_batch_s, a heartbeat per heartbeat_s, 2 events a
    second (docs/soak.md); the daemon's publisher is bound with it."""
    from fluidsense.controller.config import load_cell_config
    from fluidsense.controller.config.cell import PublisherConfig
    from fluidsense.daemon.app import bind_publisher
    from support.harness import sim_config

    assert PublisherConfig().hwm_messages == 390  # 30 s x (10 + 1 + 2) a second
    assert PublisherConfig(pressure_batch_s=0.5, heartbeat_s=2.0, queue_s=10).hwm_messages == 45
    cfg = load_cell_config(sim_config(tmp_path))
    pub = bind_publisher(cfg)
    try:
        assert pub._hwm == 390  # noqa: SLF001 - what the outlet's XPUB is given
    finally:
        pub.close()
