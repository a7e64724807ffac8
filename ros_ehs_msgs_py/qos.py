# Copyright 2026 ros_ehs contributors
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""QoS profiles of the contract as plain values (rclpy conversion lives in the nodes)."""

from __future__ import annotations

from typing import Any, NamedTuple

__all__ = ['CLOCK_QOS', 'EVENTS_QOS', 'LOCKSTEP_QOS', 'LOOP_QOS', 'QosSpec', 'RECORD_QOS']


class QosSpec(NamedTuple):
    """A QoS profile as a plain value (rclpy conversion lives in the nodes)."""

    reliability: str = 'reliable'       # 'reliable' | 'best_effort'
    depth: int = 10
    durability: str = 'volatile'        # 'volatile' | 'transient_local'
    history: str = 'keep_last'

    def as_rosbag2(self) -> dict[str, Any]:
        """Return the rosbag2 v9 ``offered_qos_profiles`` entry for this profile."""
        inf = {'sec': 9223372036, 'nsec': 854775807}
        return {'history': self.history, 'depth': int(self.depth),
                'reliability': self.reliability, 'durability': self.durability,
                'deadline': dict(inf), 'lifespan': dict(inf), 'liveliness': 'automatic',
                'liveliness_lease_duration': dict(inf),
                'avoid_ros_namespace_conventions': False}

    @classmethod
    def from_rosbag2(cls, entry: dict[str, Any] | None) -> 'QosSpec':
        """
        Return the profile of an ``offered_qos_profiles`` entry (the inverse of the above).

        Reads names and rosbag2's older enum numbers (reliability 1 reliable, 2 best effort;
        durability 1 transient local, 2 volatile); anything else (0, system default) gives
        the default. ``None`` gives the default profile.
        """
        q, d = entry or {}, cls._field_defaults
        rel, dur = q.get('reliability'), q.get('durability')
        rel = {1: 'reliable', 2: 'best_effort'}.get(rel, rel)
        dur = {1: 'transient_local', 2: 'volatile'}.get(dur, dur)
        return cls(rel if rel in ('reliable', 'best_effort') else d['reliability'],
                   int(q.get('depth') or d['depth']),
                   dur if dur in ('volatile', 'transient_local') else d['durability'])


#: Loop topics: best effort, keep last 1 (what ros2_control uses for commands).
LOOP_QOS = QosSpec('best_effort', 1)
#: Everything else (diagnostics, recorder taps of slow topics): reliable, depth 10.
RECORD_QOS = QosSpec('reliable', 10)
#: ``/clock``, as rclcpp's ClockQoS.
CLOCK_QOS = QosSpec('best_effort', 1)
#: Loop topics and ``/clock`` in lock-step: reliable, keep last 10000. Nothing waits for the
#: recorder in lock-step, and a best-effort recorder that the OS pauses for 0.3 s loses
#: ~100 states; a reliable writer holds up to 10000 samples until each reliable reader has
#: them: 2 s of a lock-step loop at 5000 steps/s (with 1000, a 0.3 s pause of the recorder
#: lost 110 states once the loop ran that fast). The history is allocated as it fills: the
#: nodes' memory is the same as with 1000. Best-effort readers (rclpy's /clock) still match.
LOCKSTEP_QOS = QosSpec('reliable', 10000)
#: Safety events: reliable, the newest 100 kept for a late subscriber (a monitor started after
#: a trip still sees it).
EVENTS_QOS = QosSpec('reliable', 100, 'transient_local')
