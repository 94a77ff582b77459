#!/usr/bin/env python3
# Copyright 2026 espdock developers
#
# Licensed under the Apache License, Version 2.0 (the 'License');
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an 'AS IS' BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""Print how many of the given words are pulses."""

import sys


def count(words):
    """Return the number of words that are 'pulse'."""
    return sum(1 for word in words if word == 'pulse')


if __name__ == '__main__':
    print(f'pulses: {count(sys.argv[1:])}')
