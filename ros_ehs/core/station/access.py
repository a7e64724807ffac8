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
Who may act from the station: the rule the engineer responsible for the rig's safety sets.

* from the machine itself (a loopback address: 127.0.0.0/8, ::1) anyone may act, as anyone
  logged on to it could call the services;
* from another address only with the token given at the station's start, compared in
  constant time; without it (or when the station was started without a token) the page is a
  read-only view;
* every decision names why, and the caller logs it with where the request came from.

A station on 127.0.0.1 (the default) is only reachable from the machine; binding another
interface is a choice the start command makes visible (``host``).
"""

from __future__ import annotations

import hmac
import ipaddress
from typing import NamedTuple

__all__ = ['Access', 'Decision']


class Decision(NamedTuple):
    """May this request act, and why (said to the page and logged)."""

    allowed: bool
    why: str


class Access:
    """The station's access rule (see the module docstring)."""

    def __init__(self, token: str = '') -> None:
        if not isinstance(token, str):
            raise ValueError(f'`token` must be a string, got {type(token).__name__}')
        if token and len(token) < 8:
            raise ValueError('`token` must be at least 8 characters (or empty: no remote '
                             'actions)')
        self._token = token

    @staticmethod
    def local(address: str | None) -> bool:
        """Return True for a loopback address (an unparsable one is not)."""
        try:
            return ipaddress.ip_address((address or '').split('%')[0]).is_loopback
        except ValueError:
            return False

    def decide(self, address: str | None, token: str | None) -> Decision:
        """Return whether a request from ``address`` carrying ``token`` may act."""
        if self.local(address):
            return Decision(True, f'from this machine ({address})')
        if not self._token:
            return Decision(False, f'read-only from {address}: this station takes actions '
                                   'only from its own machine (started without a token)')
        if token and hmac.compare_digest(token.encode(), self._token.encode()):
            return Decision(True, f'from {address} with the token')
        return Decision(False, f'read-only from {address}: '
                               + ('wrong token' if token else 'no token given'))
