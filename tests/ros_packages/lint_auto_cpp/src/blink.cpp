#include <cstdio>

int main()
{
  std::printf("blink\n");
  return 0;
}
