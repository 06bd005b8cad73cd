# Copyright 2015 Open Source Robotics Foundation, Inc.
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

import configparser

from ament_pep257.main import main
from paths import REPO
import pytest

# The one change to `ros2 pkg create`'s test: the codes setup.cfg [pydocstyle] add-ignore
# names (where the house style differs from ament's; see setup.cfg) are passed on.
SETUP_CFG = REPO / 'setup.cfg'


def house_ignores():
    """The codes of setup.cfg's [pydocstyle] add-ignore."""
    parser = configparser.ConfigParser()
    parser.read(SETUP_CFG)
    return parser.get('pydocstyle', 'add-ignore').split(',')


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257():
    rc = main(argv=['.', 'test', '--add-ignore', *house_ignores()])
    assert rc == 0, 'Found code style errors / warnings'
