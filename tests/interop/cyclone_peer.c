/* A Cyclone DDS participant built from cellcal's own IDL (idlc): it publishes the JointState, TrackerPose and
 * TargetPose samples of an input file at their times, and counts the CalibrationState and CompensatedTarget samples
 * cellcal's processes send back. Used by the interop test (tests/interop, docs/interop.md).
 *
 *   cyclone_peer DOMAIN INPUT_FILE LINGER_S OUT_JSON
 *
 * Input lines (times in ns after the start; stamps are taken from the wall clock when the sample is sent):
 *   J t_ns robot_id settled n q1 .. qn
 *   T t_ns target_id has_orientation x y z qx qy qz qw c0 .. c35
 *   P t_ns robot_id x y z qx qy qz qw n seed1 .. seedn
 * Loopback needs CYCLONEDDS_URI with the 127.0.0.1 interface and peer (the test sets it).
 */
#include <dds/dds.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "cellcal_msgs.h"

static int64_t now_ns(clockid_t c) {
  struct timespec ts;
  clock_gettime(c, &ts);
  return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static void die(const char* what, dds_return_t rc) {
  fprintf(stderr, "cyclone_peer: %s: %s\n", what, dds_strretcode(rc));
  exit(1);
}

static dds_entity_t check(dds_entity_t e, const char* what) {
  if (e < 0) die(what, e);
  return e;
}

typedef struct {
  uint64_t states, max_version, compensated, applied;
  char last_reason[257];
} counts_t;

static void drain(dds_entity_t states, dds_entity_t compensated, counts_t* c) {
  void* samples[16] = {0};
  dds_sample_info_t infos[16];
  int n;
  while ((n = dds_take(states, samples, infos, 16, 16)) > 0) {
    for (int i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      const cellcal_msg_CalibrationState* s = samples[i];
      ++c->states;
      if (s->version > c->max_version) c->max_version = s->version;
    }
    dds_return_loan(states, samples, n);
  }
  while ((n = dds_take(compensated, samples, infos, 16, 16)) > 0) {
    for (int i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      const cellcal_msg_CompensatedTarget* t = samples[i];
      ++c->compensated;
      if (t->applied) ++c->applied;
      snprintf(c->last_reason, sizeof c->last_reason, "%s", t->reason);
    }
    dds_return_loan(compensated, samples, n);
  }
}

int main(int argc, char** argv) {
  if (argc != 5) {
    fprintf(stderr, "usage: cyclone_peer DOMAIN INPUT_FILE LINGER_S OUT_JSON\n");
    return 2;
  }
  const dds_domainid_t domain = (dds_domainid_t)atoi(argv[1]);
  FILE* in = fopen(argv[2], "r");
  if (!in) {
    fprintf(stderr, "cyclone_peer: cannot open %s\n", argv[2]);
    return 1;
  }
  const double linger_s = atof(argv[3]);

  const dds_entity_t pp = check(dds_create_participant(domain, NULL, NULL), "participant");
  const dds_entity_t t_js = check(dds_create_topic(pp, &cellcal_msg_JointState_desc, "cellcal/joint_state", NULL, NULL), "topic");
  const dds_entity_t t_tp = check(dds_create_topic(pp, &cellcal_msg_TrackerPose_desc, "cellcal/tracker_pose", NULL, NULL), "topic");
  const dds_entity_t t_tg = check(dds_create_topic(pp, &cellcal_msg_TargetPose_desc, "cellcal/target_pose", NULL, NULL), "topic");
  const dds_entity_t t_cs = check(dds_create_topic(pp, &cellcal_msg_CalibrationState_desc, "cellcal/calibration_state", NULL, NULL), "topic");
  const dds_entity_t t_ct = check(dds_create_topic(pp, &cellcal_msg_CompensatedTarget_desc, "cellcal/compensated_target", NULL, NULL), "topic");

  /* QoS as cellcal's profiles (config/dds/cellcal_qos.xml): sensors best effort, calibration reliable + transient
   * local keep last 1, commands reliable keep last 100. */
  dds_qos_t* sensor = dds_create_qos();
  dds_qset_reliability(sensor, DDS_RELIABILITY_BEST_EFFORT, 0);
  dds_qset_history(sensor, DDS_HISTORY_KEEP_LAST, 100);
  dds_qos_t* command = dds_create_qos();
  dds_qset_reliability(command, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_history(command, DDS_HISTORY_KEEP_LAST, 100);
  dds_qos_t* calibration = dds_create_qos();
  dds_qset_reliability(calibration, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_durability(calibration, DDS_DURABILITY_TRANSIENT_LOCAL);
  dds_qset_history(calibration, DDS_HISTORY_KEEP_LAST, 1);

  const dds_entity_t w_js = check(dds_create_writer(pp, t_js, sensor, NULL), "writer");
  const dds_entity_t w_tp = check(dds_create_writer(pp, t_tp, sensor, NULL), "writer");
  const dds_entity_t w_tg = check(dds_create_writer(pp, t_tg, command, NULL), "writer");
  const dds_entity_t r_cs = check(dds_create_reader(pp, t_cs, calibration, NULL), "reader");
  const dds_entity_t r_ct = check(dds_create_reader(pp, t_ct, command, NULL), "reader");

  /* Readers first: a best-effort sample sent before discovery is lost. */
  const int64_t wait_end = now_ns(CLOCK_MONOTONIC) + 20000000000LL;
  for (;;) {
    dds_publication_matched_status_t a, b, c;
    dds_get_publication_matched_status(w_js, &a);
    dds_get_publication_matched_status(w_tp, &b);
    dds_get_publication_matched_status(w_tg, &c);
    if (a.current_count > 0 && b.current_count > 0 && c.current_count > 0) break;
    if (now_ns(CLOCK_MONOTONIC) > wait_end) {
      fprintf(stderr, "cyclone_peer: no cellcal reader matched within 20 s (joint_state %u, tracker_pose %u, target_pose %u)\n",
              a.current_count, b.current_count, c.current_count);
      return 1;
    }
    dds_sleepfor(DDS_MSECS(20));
  }
  dds_sleepfor(DDS_MSECS(500));

  counts_t counts = {0};
  uint64_t seq = 0, n_js = 0, n_tp = 0, n_tg = 0;
  const int64_t t0 = now_ns(CLOCK_MONOTONIC);
  char kind[2], id[65];
  long long t_ns;
  while (fscanf(in, "%1s %lld %64s", kind, &t_ns, id) == 3) {
    while (now_ns(CLOCK_MONOTONIC) < t0 + t_ns) {
      drain(r_cs, r_ct, &counts);
      dds_sleepfor(DDS_USECS(500));
    }
    ++seq;
    const uint64_t stamp = (uint64_t)now_ns(CLOCK_REALTIME);
    if (kind[0] == 'J') {
      cellcal_msg_JointState m;
      memset(&m, 0, sizeof m);
      int settled = 0, n = 0;
      if (fscanf(in, "%d %d", &settled, &n) != 2 || n < 0 || n > 16) die("bad J line", DDS_RETCODE_BAD_PARAMETER);
      double q[16];
      for (int i = 0; i < n; ++i)
        if (fscanf(in, "%lf", &q[i]) != 1) die("bad J line", DDS_RETCODE_BAD_PARAMETER);
      snprintf(m.robot_id, sizeof m.robot_id, "%s", id);
      m.source_stamp_ns = stamp;
      m.sequence_number = seq;
      m.settled = settled != 0;
      m.position_rad._length = m.position_rad._maximum = (uint32_t)n;
      m.position_rad._buffer = q;
      m.position_rad._release = false;
      if (dds_write(w_js, &m) == DDS_RETCODE_OK) ++n_js;
    } else if (kind[0] == 'T') {
      cellcal_msg_TrackerPose m;
      memset(&m, 0, sizeof m);
      int has_orientation = 0;
      int ok = fscanf(in, "%d", &has_orientation) == 1;
      for (int i = 0; i < 3; ++i) ok = ok && fscanf(in, "%lf", &m.position_m[i]) == 1;
      for (int i = 0; i < 4; ++i) ok = ok && fscanf(in, "%lf", &m.orientation_xyzw[i]) == 1;
      for (int i = 0; i < 36; ++i) ok = ok && fscanf(in, "%lf", &m.covariance[i]) == 1;
      if (!ok) die("bad T line", DDS_RETCODE_BAD_PARAMETER);
      snprintf(m.target_id, sizeof m.target_id, "%s", id);
      m.source_stamp_ns = stamp;
      m.sequence_number = seq;
      m.has_orientation = has_orientation != 0;
      m.valid = true;
      if (dds_write(w_tp, &m) == DDS_RETCODE_OK) ++n_tp;
    } else if (kind[0] == 'P') {
      cellcal_msg_TargetPose m;
      memset(&m, 0, sizeof m);
      int ok = 1, n = 0;
      double seed_rad[16];
      for (int i = 0; i < 3; ++i) ok = ok && fscanf(in, "%lf", &m.position_m[i]) == 1;
      for (int i = 0; i < 4; ++i) ok = ok && fscanf(in, "%lf", &m.orientation_xyzw[i]) == 1;
      ok = ok && fscanf(in, "%d", &n) == 1 && n >= 0 && n <= 16;
      for (int i = 0; ok && i < n; ++i) ok = fscanf(in, "%lf", &seed_rad[i]) == 1;
      if (!ok) die("bad P line", DDS_RETCODE_BAD_PARAMETER);
      m.seed_position_rad._length = m.seed_position_rad._maximum = (uint32_t)n;
      m.seed_position_rad._buffer = seed_rad;
      m.seed_position_rad._release = false;
      snprintf(m.robot_id, sizeof m.robot_id, "%s", id);
      m.source_stamp_ns = stamp;
      m.sequence_number = seq;
      if (dds_write(w_tg, &m) == DDS_RETCODE_OK) ++n_tg;
    } else {
      die("unknown line kind", DDS_RETCODE_BAD_PARAMETER);
    }
  }
  fclose(in);
  const int64_t linger_end = now_ns(CLOCK_MONOTONIC) + (int64_t)(linger_s * 1e9);
  while (now_ns(CLOCK_MONOTONIC) < linger_end) {
    drain(r_cs, r_ct, &counts);
    dds_sleepfor(DDS_MSECS(10));
  }
  drain(r_cs, r_ct, &counts);

  FILE* out = fopen(argv[4], "w");
  if (!out) {
    fprintf(stderr, "cyclone_peer: cannot write %s\n", argv[4]);
    return 1;
  }
  /* reason: cellcal's own text (no quotes or backslashes in it). */
  fprintf(out,
          "{\"published\": {\"joint_state\": %" PRIu64 ", \"tracker_pose\": %" PRIu64 ", \"target_pose\": %" PRIu64
          "}, \"received\": {\"calibration_state\": %" PRIu64 ", \"max_version\": %" PRIu64
          ", \"compensated_target\": %" PRIu64 ", \"applied\": %" PRIu64 ", \"last_reason\": \"%s\"}}\n",
          n_js, n_tp, n_tg, counts.states, counts.max_version, counts.compensated, counts.applied, counts.last_reason);
  fclose(out);
  dds_delete_qos(sensor);
  dds_delete_qos(command);
  dds_delete_qos(calibration);
  dds_delete(pp);
  return 0;
}
