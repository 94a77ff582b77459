// Copyright 2026 espdock developers
//
// Licensed under the Apache License, Version 2.0 (the "License");
// you may not use this file except in compliance with the License.
// You may obtain a copy of the License at
//
//     http://www.apache.org/licenses/LICENSE-2.0
//
// Unless required by applicable law or agreed to in writing, software
// distributed under the License is distributed on an "AS IS" BASIS,
// WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
// See the License for the specific language governing permissions and
// limitations under the License.

#include <iostream>
#include <string>

int main(int argc, char ** argv)
{
  int pulses = 0;
  for (int i = 1; i < argc; ++i) {
    if (std::string(argv[i]) == "pulse") {
      ++pulses;
    }
  }
  std::cout << "pulses: " << pulses << std::endl;
  return 0;
}
