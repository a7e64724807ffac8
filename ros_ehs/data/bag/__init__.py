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
"""
rosbag2-compatible MCAP bags: the only reader and writer in ros_ehs (no rclpy).

``BagWriter`` writes a bag directory; ``open_bag`` reads ours, rosbag2's and truncated ones;
``load_experiment`` extracts the arrays identification needs from the contract topics;
``load_experiments`` splits a recording with missing samples into its contiguous runs.
"""

from ros_ehs.data.bag.definitions import full_definition, type_hash
from ros_ehs.data.bag.reader import Bag, BagMessage, open_bag, TopicInfo
from ros_ehs.data.bag.writer import BagWriter

__all__ = ['Bag', 'BagMessage', 'BagWriter', 'TopicInfo', 'full_definition', 'open_bag',
           'type_hash']
