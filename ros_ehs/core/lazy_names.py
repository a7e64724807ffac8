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
A package's names imported from their modules when first used (PEP 562).

:func:`attach` is ``lazy_loader.attach(name, submod_attrs=...)`` (scientific-python SPEC 1)
for submodule attributes. That library has no rosdep key, so a package built with colcon
after ``rosdep install`` would not find it at run time; package.xml names every dependency
(``test/test_packaging.py`` checks it against the imports).
"""

from __future__ import annotations

import importlib
import sys
from typing import Callable

__all__ = ['attach']


def attach(package: str, submod_attrs: dict[str, list[str]]
           ) -> tuple[Callable[[str], object], Callable[[], list[str]], list[str]]:
    """
    Return ``__getattr__``, ``__dir__`` and ``__all__`` for ``package``.

    ``submod_attrs`` maps each submodule to the names it gives the package; a name's module
    is imported on its first use, and the name is then kept on the package.
    """
    home = {name: mod for mod, names in submod_attrs.items() for name in names}
    names = sorted(home)

    def __getattr__(name: str) -> object:
        if name not in home:
            raise AttributeError(f'module {package!r} has no attribute {name!r}')
        value = getattr(importlib.import_module(f'{package}.{home[name]}'), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return list(names)

    return __getattr__, __dir__, list(names)
