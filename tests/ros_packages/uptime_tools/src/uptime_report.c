#include <stdio.h>

int main(void) {
  FILE *f = fopen("/proc/uptime", "r");
  double up = 0.0;
  if (f == NULL || fscanf(f, "%lf", &up) != 1) {
    fprintf(stderr, "uptime_report: cannot read /proc/uptime\n");
    return 1;
  }
  fclose(f);
  printf("uptime_report: up %.0f s\n", up);
  return 0;
}
