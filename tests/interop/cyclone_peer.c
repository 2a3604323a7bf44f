/* A Cyclone DDS participant built from cellcal's own IDL (idlc): it publishes the JointState, TrackerPose and
 * TargetPose samples of an input file at their times, and counts the CalibrationState and CompensatedTarget samples
 * cellcal's processes send back. Used by the interop test (tests/interop, docs/interop.md).
 *
 *   cyclone_peer DOMAIN INPUT_FILE LINGER_S OUT_JSON [ROS_POSE_TOPIC|- [ROS_DESCRIPTION_TOPIC]]
 *
 * With ROS_POSE_TOPIC (a DDS topic, e.g. rt/cellcal/corrected_pose) it is also a ROS 2 node as rmw_cyclonedds puts
 * one on the wire: it publishes the robot's joints as sensor_msgs/JointState on rt/joint_states (R lines; types from
 * idl/ros2_msgs.idl, ROS 2's default QoS: reliable, keep last 10) and reads geometry_msgs/PoseStamped on
 * ROS_POSE_TOPIC; it then waits for a reader of rt/joint_states instead of cellcal/joint_state.
 * With ROS_DESCRIPTION_TOPIC (e.g. rt/robot_description) it reads std_msgs/String there as RViz reads
 * robot_description (reliable, transient local, keep last 1), counts the samples and writes the last one to
 * OUT_JSON.urdf; OUT_JSON then also has the last ok CalibrationState's version and parameter values.
 * With an empty INPUT_FILE it only listens, for at most LINGER_S, until a robot_description came (a late joiner).
 *
 * Input lines (times in ns after the start; stamps are taken from the wall clock when the sample is sent):
 *   J t_ns robot_id settled n q1 .. qn
 *   T t_ns target_id has_orientation x y z qx qy qz qw c0 .. c35
 *   P t_ns robot_id x y z qx qy qz qw n seed1 .. seedn
 *   R t_ns frame_id n name1 .. namen q1 .. qn        (header.stamp: the wall clock when sent)
 * Loopback needs CYCLONEDDS_URI with the 127.0.0.1 interface and peer (the test sets it).
 */
#include <dds/dds.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "cellcal_msgs.h"
#include "ros2_msgs.h"

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

#define KEEP 256
typedef struct {
  uint64_t states, max_version, compensated, applied;
  char last_reason[257];
  /* ROS 2: PoseStamped received, and the applied corrections and poses in arrival order (the first KEEP of each) */
  uint64_t poses;
  char last_frame_id[65];
  double corrected[KEEP][7], posed[KEEP][7];
  /* robot_description: samples received and the last one; the last ok CalibrationState's version and values */
  uint64_t descriptions;
  char* last_description;
  uint64_t ok_version;
  uint32_t ok_n;
  double ok_values[128];
} counts_t;

static void drain(dds_entity_t states, dds_entity_t compensated, dds_entity_t poses, dds_entity_t descriptions,
                  counts_t* c) {
  void* samples[16] = {0};
  dds_sample_info_t infos[16];
  int n;
  while ((n = dds_take(states, samples, infos, 16, 16)) > 0) {
    for (int i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      const cellcal_msg_CalibrationState* s = samples[i];
      ++c->states;
      if (s->version > c->max_version) c->max_version = s->version;
      if (s->health == cellcal_msg_HEALTH_OK && s->parameter_values._length <= 128) {
        c->ok_version = s->version;
        c->ok_n = s->parameter_values._length;
        for (uint32_t k = 0; k < c->ok_n; ++k) c->ok_values[k] = s->parameter_values._buffer[k];
      }
    }
    dds_return_loan(states, samples, n);
  }
  while ((n = dds_take(compensated, samples, infos, 16, 16)) > 0) {
    for (int i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      const cellcal_msg_CompensatedTarget* t = samples[i];
      ++c->compensated;
      if (t->applied) {
        if (c->applied < KEEP) {
          for (int k = 0; k < 3; ++k) c->corrected[c->applied][k] = t->corrected_position_m[k];
          for (int k = 0; k < 4; ++k) c->corrected[c->applied][3 + k] = t->corrected_orientation_xyzw[k];
        }
        ++c->applied;
      }
      snprintf(c->last_reason, sizeof c->last_reason, "%s", t->reason);
    }
    dds_return_loan(compensated, samples, n);
  }
  while (poses > 0 && (n = dds_take(poses, samples, infos, 16, 16)) > 0) {
    for (int i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      const geometry_msgs_msg_dds__PoseStamped_* p = samples[i];
      if (c->poses < KEEP) {
        const double v[7] = {p->pose.position.x,    p->pose.position.y,    p->pose.position.z,   p->pose.orientation.x,
                             p->pose.orientation.y, p->pose.orientation.z, p->pose.orientation.w};
        memcpy(c->posed[c->poses], v, sizeof v);
      }
      ++c->poses;
      snprintf(c->last_frame_id, sizeof c->last_frame_id, "%s", p->header.frame_id ? p->header.frame_id : "");
    }
    dds_return_loan(poses, samples, n);
  }
  while (descriptions > 0 && (n = dds_take(descriptions, samples, infos, 16, 16)) > 0) {
    for (int i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      const std_msgs_msg_dds__String_* d = samples[i];
      ++c->descriptions;
      free(c->last_description);
      c->last_description = strdup(d->data ? d->data : "");
    }
    dds_return_loan(descriptions, samples, n);
  }
}

int main(int argc, char** argv) {
  if (argc < 5 || argc > 7) {
    fprintf(stderr, "usage: cyclone_peer DOMAIN INPUT_FILE LINGER_S OUT_JSON [ROS_POSE_TOPIC|- [ROS_DESCRIPTION_TOPIC]]\n");
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
  const int ros = argc >= 6 && strcmp(argv[5], "-") != 0;
  dds_entity_t w_ros_js = 0, r_ros_pose = 0;
  dds_qos_t* ros_default = dds_create_qos(); /* ROS 2's default: reliable, volatile, keep last 10 */
  dds_qset_reliability(ros_default, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_history(ros_default, DDS_HISTORY_KEEP_LAST, 10);
  if (ros) {
    const dds_entity_t t_ros_js =
        check(dds_create_topic(pp, &sensor_msgs_msg_dds__JointState__desc, "rt/joint_states", NULL, NULL), "topic");
    const dds_entity_t t_ros_pose =
        check(dds_create_topic(pp, &geometry_msgs_msg_dds__PoseStamped__desc, argv[5], NULL, NULL), "topic");
    w_ros_js = check(dds_create_writer(pp, t_ros_js, ros_default, NULL), "writer");
    r_ros_pose = check(dds_create_reader(pp, t_ros_pose, ros_default, NULL), "reader");
  }
  dds_entity_t r_description = 0;
  if (argc == 7) {
    const dds_entity_t t_description =
        check(dds_create_topic(pp, &std_msgs_msg_dds__String__desc, argv[6], NULL, NULL), "topic");
    r_description = check(dds_create_reader(pp, t_description, calibration, NULL), "reader");
  }
  /* An empty input file: a late joiner, it only listens. */
  const int listen_only = fgetc(in) == EOF;
  rewind(in);

  /* Readers first: a best-effort sample sent before discovery is lost. */
  const int64_t wait_end = now_ns(CLOCK_MONOTONIC) + 20000000000LL;
  for (; !listen_only;) {
    dds_publication_matched_status_t a, b, c;
    dds_get_publication_matched_status(ros ? w_ros_js : w_js, &a);
    dds_get_publication_matched_status(w_tp, &b);
    dds_get_publication_matched_status(w_tg, &c);
    if (a.current_count > 0 && b.current_count > 0 && c.current_count > 0) break;
    if (now_ns(CLOCK_MONOTONIC) > wait_end) {
      fprintf(stderr, "cyclone_peer: no cellcal reader matched within 20 s (%s %u, tracker_pose %u, target_pose %u)\n",
              ros ? "rt/joint_states" : "joint_state", a.current_count, b.current_count, c.current_count);
      return 1;
    }
    dds_sleepfor(DDS_MSECS(20));
  }
  if (!listen_only) dds_sleepfor(DDS_MSECS(500));

  static counts_t counts; /* large: not on the stack */
  uint64_t seq = 0, n_js = 0, n_tp = 0, n_tg = 0, n_ros_js = 0;
  const int64_t t0 = now_ns(CLOCK_MONOTONIC);
  char kind[2], id[65];
  long long t_ns;
  while (fscanf(in, "%1s %lld %64s", kind, &t_ns, id) == 3) {
    while (now_ns(CLOCK_MONOTONIC) < t0 + t_ns) {
      drain(r_cs, r_ct, r_ros_pose, r_description, &counts);
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
    } else if (kind[0] == 'R') {
      if (!ros) die("R line without ROS_POSE_TOPIC", DDS_RETCODE_BAD_PARAMETER);
      sensor_msgs_msg_dds__JointState_ m;
      memset(&m, 0, sizeof m);
      int n = 0;
      if (fscanf(in, "%d", &n) != 1 || n < 0 || n > 16) die("bad R line", DDS_RETCODE_BAD_PARAMETER);
      char names[16][65];
      char* name_ptrs[16];
      double q[16];
      for (int i = 0; i < n; ++i) {
        if (fscanf(in, "%64s", names[i]) != 1) die("bad R line", DDS_RETCODE_BAD_PARAMETER);
        name_ptrs[i] = names[i];
      }
      for (int i = 0; i < n; ++i)
        if (fscanf(in, "%lf", &q[i]) != 1) die("bad R line", DDS_RETCODE_BAD_PARAMETER);
      m.header.stamp.sec = (int32_t)(stamp / 1000000000ULL);
      m.header.stamp.nanosec = (uint32_t)(stamp % 1000000000ULL);
      m.header.frame_id = id;
      m.name._length = m.name._maximum = (uint32_t)n;
      m.name._buffer = name_ptrs;
      m.name._release = false;
      m.position._length = m.position._maximum = (uint32_t)n;
      m.position._buffer = q;
      m.position._release = false;
      if (dds_write(w_ros_js, &m) == DDS_RETCODE_OK) ++n_ros_js;
    } else {
      die("unknown line kind", DDS_RETCODE_BAD_PARAMETER);
    }
  }
  fclose(in);
  const int64_t linger_end = now_ns(CLOCK_MONOTONIC) + (int64_t)(linger_s * 1e9);
  while (now_ns(CLOCK_MONOTONIC) < linger_end) {
    drain(r_cs, r_ct, r_ros_pose, r_description, &counts);
    if (listen_only && r_description > 0 && counts.descriptions > 0) break; /* the late joiner has what it came for */
    dds_sleepfor(DDS_MSECS(10));
  }
  drain(r_cs, r_ct, r_ros_pose, r_description, &counts);

  FILE* out = fopen(argv[4], "w");
  if (!out) {
    fprintf(stderr, "cyclone_peer: cannot write %s\n", argv[4]);
    return 1;
  }
  /* The k-th PoseStamped against the k-th applied correction (both reliable, in order). */
  double pose_max_diff = 0;
  const uint64_t pairs = counts.poses < counts.applied ? counts.poses : counts.applied;
  for (uint64_t k = 0; k < pairs && k < KEEP; ++k)
    for (int i = 0; i < 7; ++i) {
      const double d = counts.posed[k][i] - counts.corrected[k][i];
      if ((d < 0 ? -d : d) > pose_max_diff) pose_max_diff = d < 0 ? -d : d;
    }
  /* reason and frame_id: cellcal's own text (no quotes or backslashes in it). */
  fprintf(out,
          "{\"published\": {\"joint_state\": %" PRIu64 ", \"tracker_pose\": %" PRIu64 ", \"target_pose\": %" PRIu64
          ", \"ros_joint_state\": %" PRIu64 "}, \"received\": {\"calibration_state\": %" PRIu64
          ", \"max_version\": %" PRIu64 ", \"compensated_target\": %" PRIu64 ", \"applied\": %" PRIu64
          ", \"last_reason\": \"%s\", \"pose_stamped\": %" PRIu64 ", \"last_frame_id\": \"%s\""
          ", \"pose_max_diff\": %.17g, \"robot_description\": %" PRIu64 ", \"ok_version\": %" PRIu64
          ", \"ok_values\": [",
          n_js, n_tp, n_tg, n_ros_js, counts.states, counts.max_version, counts.compensated, counts.applied,
          counts.last_reason, counts.poses, counts.last_frame_id, pose_max_diff, counts.descriptions, counts.ok_version);
  for (uint32_t k = 0; k < counts.ok_n; ++k) fprintf(out, "%s%.17g", k ? ", " : "", counts.ok_values[k]);
  fprintf(out, "]}}\n");
  fclose(out);
  if (counts.last_description) {
    char path[4096];
    snprintf(path, sizeof path, "%s.urdf", argv[4]);
    FILE* u = fopen(path, "w");
    if (!u) {
      fprintf(stderr, "cyclone_peer: cannot write %s\n", path);
      return 1;
    }
    fputs(counts.last_description, u);
    fclose(u);
    free(counts.last_description);
  }
  dds_delete_qos(sensor);
  dds_delete_qos(command);
  dds_delete_qos(calibration);
  dds_delete_qos(ros_default);
  dds_delete(pp);
  return 0;
}
