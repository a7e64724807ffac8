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
The one error hierarchy of ros_ehs.

Every error the core raises on purpose derives from :class:`EhsError`, and also from the
built-in exception a caller would expect (``ValueError`` for bad values), so plain
``except ValueError`` keeps working.
"""

__all__ = [
    'BagError',
    'BagWriteError',
    'DataError',
    'EhsError',
    'IdentificationWarning',
    'InputError',
    'ParameterError',
]


class EhsError(Exception):
    """Base class of every ros_ehs error."""


class ParameterError(EhsError, ValueError):
    """A parameter is unknown, non-finite or outside its declared range."""


class InputError(EhsError, ValueError):
    """A model or controller input (state, current, force, dt) is malformed or non-finite."""


class DataError(EhsError, ValueError):
    """Recorded data is unusable: too short, no excitation, wrong shape or type."""


class BagError(DataError):
    """A bag is missing, truncated, foreign or lacks the needed topics."""


class BagWriteError(BagError):
    """
    Writing a bag failed (disk full, write error): nothing more is written.

    ``path`` is the file that failed, ``free_bytes`` the space left on its filesystem (-1 if
    unknown), ``errno`` the OS error number.
    """

    def __init__(self, message: str, path: str = '', free_bytes: int = -1,
                 errno: int = 0) -> None:
        super().__init__(message)
        self.path = path
        self.free_bytes = free_bytes
        self.errno = errno


class IdentificationWarning(UserWarning):
    """A fitted parameter is not identifiable from the data (or sits on a bound)."""
