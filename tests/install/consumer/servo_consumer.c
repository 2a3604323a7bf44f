/* Uses the installed cellcal::servo from C, as a controller bridge would: a handle for the installed cell file's robot
 * (its calibration feed joins the cell's DDS domain), a stream of setpoints answered cycle by cycle, the feed's state
 * in words. No engine runs here: every setpoint comes back as given, said as no_calibration; a setpoint of the wrong
 * size is refused; an unknown robot is named. Exit 0 only when all of that holds. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "cellcal/servo_compensation.h"

int main(int argc, char** argv) {
  if (argc != 2) {
    fprintf(stderr, "usage: servo_consumer CELL_FILE\n");
    return 2;
  }
  char why[512];
  if (cellcal_servo_create(argv[1], "no_such_robot", why, sizeof why) != NULL || strstr(why, "no_such_robot") == NULL) {
    fprintf(stderr, "servo_consumer: an unknown robot was not refused by name: %s\n", why);
    return 1;
  }
  cellcal_servo* s = cellcal_servo_create(argv[1], "tx60", why, sizeof why);
  if (!s) {
    fprintf(stderr, "servo_consumer: %s\n", why);
    return 1;
  }
  const int n = cellcal_servo_joints(s);
  double q[7] = {0.1, -0.4, 1.2, 0.05, 0.6, -0.2, 0}, out[7];
  int failures = 0;
  for (int k = 0; k < 250; ++k) { /* one second at 250 Hz */
    cellcal_servo_answer a;
    q[0] = 0.1 + 0.001 * k;
    const int status = cellcal_servo_correct(s, (int64_t)k * 4000000, q, n, out, &a);
    if (status != CELLCAL_SERVO_NO_CALIBRATION || a.version != 0 || out[0] != q[0]) ++failures;
  }
  cellcal_servo_answer bad;
  if (cellcal_servo_correct(s, 1000000000, q, n + 1, out, &bad) != CELLCAL_SERVO_BAD_SETPOINT) ++failures;
  char text[256];
  cellcal_servo_describe(s, text, sizeof text);
  printf("servo_consumer: %d joints, version %llu, feed: %s\n", n, (unsigned long long)cellcal_servo_version(s), text);
  cellcal_servo_destroy(s);
  if (failures) fprintf(stderr, "servo_consumer: %d answers not as expected\n", failures);
  return failures == 0 && strstr(text, "tx60: no calibration received yet") != NULL ? 0 : 1;
}
