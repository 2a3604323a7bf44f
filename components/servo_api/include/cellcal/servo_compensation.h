/* cellcal's compensation inside a controller's own loop, for bridges in C or any language with a C FFI.
 *
 * One handle per robot: a real-time compensator (core/servo/realtime_compensator.hpp) and its calibration feed
 * (components calibration_feed.hpp: the cell's ok calibrations of the robot over DDS, prepared on the feed's own
 * thread). The controller's thread calls cellcal_servo_correct() once per cycle; it allocates nothing, takes no lock,
 * makes no system call and blocks on nothing. Link: find_package(cellcal) and target cellcal::servo
 * (libcellcal_servo.so).
 *
 *   char why[512];
 *   cellcal_servo* s = cellcal_servo_create("/etc/cellcal/cell.yaml", "kr150", why, sizeof why);
 *   if (!s) { fprintf(stderr, "%s\n", why); return 1; }
 *   ... per cycle: cellcal_servo_correct(s, ipoc_ns, q_setpoint, 6, q_command, NULL);
 *   cellcal_servo_destroy(s);
 *
 * Threads: create and destroy on any thread but not while correct() runs; correct() and version() on the
 * controller's thread; describe() on any thread. */
#ifndef CELLCAL_SERVO_COMPENSATION_H
#define CELLCAL_SERVO_COMPENSATION_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct cellcal_servo cellcal_servo;

/* What became of a setpoint (core's ServoStatus). */
enum cellcal_servo_status {
  CELLCAL_SERVO_APPLIED = 0,        /* corrected (blended between versions while one comes in) */
  CELLCAL_SERVO_HELD = 1,           /* the version refused it: the last correction, held and fading */
  CELLCAL_SERVO_NO_CALIBRATION = 2, /* no ok calibration yet: the setpoint as given */
  CELLCAL_SERVO_BAD_SETPOINT = 3    /* wrong joint count or not finite: the setpoint as given */
};

typedef struct cellcal_servo_answer {
  int status;        /* enum cellcal_servo_status */
  int outcome;       /* core's CompensationOutcome: 0 applied, 1 clamped, 3 unreachable, 5 outside_calibration, ... */
  uint64_t version;  /* answering (0: none yet) */
  uint64_t from_version;
  double weight;             /* of `version` in a blend */
  double hold_fraction;      /* held: the share of the last correction still applied */
  double predicted_sigma_m;  /* the version's predicted 1-sigma position error at the answer (NaN without one) */
} cellcal_servo_answer;

/* The compensator and feed of robot `robot_id` of the cell file (its compensation bounds and blend time, its dds
 * settings). NULL on failure, with the reason in `error` (truncated to error_size bytes; error may be NULL). */
cellcal_servo* cellcal_servo_create(const char* cell_file, const char* robot_id, char* error, size_t error_size);

/* Controller thread, once per cycle: the joints to command for a joint setpoint of `joints` values (q_out_rad holds
 * `joints` values; the setpoint's own where nothing is applied). `answer` may be NULL. Returns the status. */
int cellcal_servo_correct(cellcal_servo* servo, int64_t cycle_stamp_ns, const double* q_setpoint_rad, int joints,
                          double* q_out_rad, cellcal_servo_answer* answer);

/* Controller thread: the version answering (0: none yet). */
uint64_t cellcal_servo_version(const cellcal_servo* servo);

/* The robot's joint count. */
int cellcal_servo_joints(const cellcal_servo* servo);

/* The feed's state in words ("kr150: applying v12; holding it: v13 degraded; ..."), NUL-terminated in `text`
 * (truncated to size bytes). Returns the full length. Not for the controller's thread. */
size_t cellcal_servo_describe(const cellcal_servo* servo, char* text, size_t size);

void cellcal_servo_destroy(cellcal_servo* servo);

#ifdef __cplusplus
}
#endif

#endif
