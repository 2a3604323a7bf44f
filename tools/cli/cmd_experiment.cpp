// `cellcal experiment paper`: the published experiments on the simulated robot (core/paper_experiment.hpp).
#include <algorithm>
#include <cstdio>
#include <unistd.h>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "cellcal/lab/paper_experiment.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

struct ExperimentArgs {
  std::string robot = defaultRobotFile("staubli_tx60.yaml");
  std::uint64_t seed = 1;
  std::string json_path, plot_dir;
  bool position_only = false;
  bool quiet = false;
  double forgetting = 0.95;
  int seeds = 1;
  int candidates = 0;
};

double improvement(double before, double after) { return before > 0 ? 100.0 * (before - after) / before : 0.0; }

std::string runLabel(const MaintenanceRun& r) {
  std::string s = r.algorithm;
  if (r.prior) s += "+prior";
  if (r.pose_selection == "i-optimal") s += "+select";
  if (r.forgetting < 1.0) {
    char b[32];
    std::snprintf(b, sizeof b, " lambda=%.2f", r.forgetting);
    s += b;
  }
  return s;
}

// Over many random robots: how often every continuous update stays within 1.5x the noise floor, per run.
void printSeedSummary(const RobotModel& robot, PaperExperimentConfig cfg, std::uint64_t first, int seeds,
                      std::ostream& os) {
  struct Tally {
    int within = 0;
    double worst_sum = 0, worst_max = 0, verify_impr_sum = 0;
  };
  std::vector<std::string> labels;
  std::vector<Tally> tally;
  for (int s = 0; s < seeds; ++s) {
    cfg.sim.seed = first + static_cast<std::uint64_t>(s);
    const auto r = runPaperExperiment(robot, cfg);
    if (labels.empty())
      for (const auto& m : r.maintenance) {
        labels.push_back(m.mode + " " + runLabel(m) + " " + std::to_string(m.updated_poses));
        tally.emplace_back();
      }
    for (size_t i = 0; i < r.maintenance.size(); ++i) {
      const auto& m = r.maintenance[i];
      tally[i].within += m.worst_verify_to_floor <= 1.5;
      tally[i].worst_sum += m.worst_verify_to_floor;
      tally[i].worst_max = std::max(tally[i].worst_max, m.worst_verify_to_floor);
      tally[i].verify_impr_sum += improvement(m.verify_before_m, m.verify_after_m);
    }
    if (::isatty(2)) std::fprintf(stderr, "\rseed %d/%d", s + 1, seeds);  // progress only on a terminal
  }
  if (::isatty(2)) std::fprintf(stderr, "\n");
  char line[256];
  os << "Over " << seeds << " random robots (seeds " << first << ".." << first + seeds - 1
     << "): share whose every update ends within 1.5x the noise floor\n";
  os << "  run                                  within 1.5x   mean worst   max worst   mean verify impr%\n";
  for (size_t i = 0; i < labels.size(); ++i) {
    std::snprintf(line, sizeof line, "  %-36s  %9.1f%%  %11.2f  %10.2f  %18.1f\n", labels[i].c_str(),
                  100.0 * tally[i].within / seeds, tally[i].worst_sum / seeds, tally[i].worst_max,
                  tally[i].verify_impr_sum / seeds);
    os << line;
  }
}

void printTables(const PaperExperimentResult& r, const PaperExperimentConfig& cfg, std::ostream& os) {
  char line[256];
  os << "Pose-number sweep (paper Table 2): RLS from the prior, group 0 of the simulated "
     << "robot; mean position error, mm\n";
  os << "  poses  identification  verification\n";
  for (const auto& s : r.sweep) {
    std::snprintf(line, sizeof line, "  %5d  %14.4f  %12.4f\n", s.poses, s.ident_mean_m * 1e3, s.verify_mean_m * 1e3);
    os << line;
  }
  os << "\nAccuracy maintenance (paper Table 4): " << cfg.groups << " groups " << cfg.hours_between_groups
     << " h apart; group 0 = initial calibration with " << cfg.identification_poses
     << " poses; means over the update groups 1.." << cfg.groups - 1 << ", mm\n";
  os << "  mode        algorithm          poses  ident before  after  impr%   verify before  after  impr%  "
        "worst verify/floor\n";
  for (const auto& m : r.maintenance) {
    std::snprintf(line, sizeof line, "  %-10s  %-17s  %5d  %12.4f %6.4f %6.1f   %13.4f %6.4f %6.1f  %8.2f\n",
                  m.mode.c_str(), runLabel(m).c_str(), m.updated_poses, m.ident_before_m * 1e3,
                  m.ident_after_m * 1e3, improvement(m.ident_before_m, m.ident_after_m), m.verify_before_m * 1e3,
                  m.verify_after_m * 1e3, improvement(m.verify_before_m, m.verify_after_m), m.worst_verify_to_floor);
    os << line;
  }
  os << "\nVerification error after each update, mm (group: hours)\n  mode        algorithm          poses";
  for (int g = 0; g < cfg.groups; ++g) {
    std::snprintf(line, sizeof line, "   g%d:%3.0fh", g, g * cfg.hours_between_groups);
    os << line;
  }
  os << "\n";
  for (const auto& m : r.maintenance) {
    std::snprintf(line, sizeof line, "  %-10s  %-17s  %5d", m.mode.c_str(), runLabel(m).c_str(), m.updated_poses);
    os << line;
    for (const auto& g : m.groups) {
      std::snprintf(line, sizeof line, "  %8.4f", g.verify_after_m * 1e3);
      os << line;
    }
    os << "\n";
  }
  std::snprintf(line, sizeof line, "  %-10s  %-17s  %5s", "noise", "floor", "");
  os << line;
  for (const auto& g : r.maintenance.front().groups) {
    std::snprintf(line, sizeof line, "  %8.4f", g.noise_floor_m * 1e3);
    os << line;
  }
  std::snprintf(line, sizeof line,
                "\n\nNoise floor (mean |measured - true| on verification poses): %.4f mm; nominal model error: %.4f mm\n"
                "Timing: RLS %.2f us per pose (linearization + update), LM 50-pose initial solve %.2f ms\n",
                r.noise_floor_m * 1e3, r.true_error_nominal_m * 1e3, r.rls_time_per_pose_s * 1e6,
                r.lm_time_50_s * 1e3);
  os << line;
}

nlohmann::json toJson(const PaperExperimentResult& r) {
  nlohmann::json j;
  j["pose_sweep"] = nlohmann::json::array();
  for (const auto& s : r.sweep)
    j["pose_sweep"].push_back({{"poses", s.poses}, {"ident_mean_mm", s.ident_mean_m * 1e3},
                               {"verify_mean_mm", s.verify_mean_m * 1e3}});
  j["maintenance"] = nlohmann::json::array();
  for (const auto& m : r.maintenance) {
    nlohmann::json row = {{"mode", m.mode},
                          {"algorithm", m.algorithm},
                          {"updated_poses", m.updated_poses},
                          {"ident_before_mm", m.ident_before_m * 1e3},
                          {"ident_after_mm", m.ident_after_m * 1e3},
                          {"verify_before_mm", m.verify_before_m * 1e3},
                          {"verify_after_mm", m.verify_after_m * 1e3},
                          {"prior", m.prior},
                          {"forgetting", m.forgetting},
                          {"pose_selection", m.pose_selection},
                          {"worst_verify_to_noise_floor", m.worst_verify_to_floor}};
    for (const auto& g : m.groups)
      row["groups"].push_back({{"group", g.group},
                               {"t_h", g.t_h},
                               {"poses_used", g.poses_used},
                               {"ident_before_mm", g.ident_before_m * 1e3},
                               {"ident_after_mm", g.ident_after_m * 1e3},
                               {"verify_before_mm", g.verify_before_m * 1e3},
                               {"verify_after_mm", g.verify_after_m * 1e3},
                               {"noise_floor_mm", g.noise_floor_m * 1e3},
                               {"update_time_s", g.update_time_s}});
    j["maintenance"].push_back(row);
  }
  j["noise_floor_mm"] = r.noise_floor_m * 1e3;
  j["nominal_model_error_mm"] = r.true_error_nominal_m * 1e3;
  j["rls_time_per_pose_us"] = r.rls_time_per_pose_s * 1e6;
  j["lm_time_50_poses_ms"] = r.lm_time_50_s * 1e3;
  return j;
}

void writePlots(const PaperExperimentResult& r, const std::string& dir) {
  std::string err;
  // Figure 1: verification error per group, before/after, for each run (like the paper's per-group bars).
  // LM with the RLS prior overlaps RLS; leave it out of the figure (it is in the tables and JSON).
  std::vector<const MaintenanceRun*> runs;
  for (const auto& m : r.maintenance)
    if (!m.prior) runs.push_back(&m);
  std::ostringstream data;
  data << "x t_h floor";
  for (const auto* m : runs) data << " \"" << m->mode << " " << runLabel(*m) << " " << m->updated_poses << "\"";
  data << "\n";
  const size_t groups = r.maintenance.front().groups.size();
  for (size_t g = 0; g < groups; ++g) {
    // Two rows per group: before (x = g - 0.2) and after (x = g + 0.2).
    for (int after = 0; after < 2; ++after) {
      data << g + (after ? 0.15 : -0.15) << " " << r.maintenance.front().groups[g].t_h << " "
           << r.maintenance.front().groups[g].noise_floor_m * 1e3;
      for (const auto* m : runs)
        data << " " << (after ? m->groups[g].verify_after_m : m->groups[g].verify_before_m) * 1e3;
      data << "\n";
    }
  }
  // One panel per schedule (periodic; continuous with 15 and with 20 fresh poses), each run of it a line: nine runs
  // on one axis hid each other.
  std::vector<std::pair<std::string, std::vector<size_t>>> panels;
  for (size_t k = 0; k < runs.size(); ++k) {
    const std::string panel = runs[k]->mode == "periodic" ? "periodic (" + std::to_string(runs[k]->updated_poses) + " poses)"
                                                          : "continuous, " + std::to_string(runs[k]->updated_poses) + " poses";
    auto it = std::find_if(panels.begin(), panels.end(), [&](const auto& p) { return p.first == panel; });
    if (it == panels.end()) it = panels.insert(panels.end(), {panel, {}});
    it->second.push_back(k);
  }
  std::ostringstream gp;
  gp << "set multiplot layout 1," << panels.size()
     << " title 'Verification error per group: before (left) and after (right) each update'\n"
     << "set xlabel 'group (2 h apart)'\nset ylabel 'mean position error (mm)'\nset logscale y\n"
     << "set key top right font ',9'\nset grid\nset xtics 1\nset xrange [-0.5:" << groups - 0.5 << "]\n";
  for (const auto& [panel, members] : panels) {
    gp << "set title '" << panel << "'\nplot ";
    for (size_t k : members) {
      const auto* m = runs[k];
      gp << "datafile using 1:" << 4 + k << " skip 1 with linespoints title '" << runLabel(*m) << "', ";
    }
    gp << "datafile using 1:3 skip 1 with lines lw 2 dt 2 lc 'black' title 'noise floor'\n";
  }
  gp << "unset multiplot\n";
  if (!renderGnuplot(dir, "maintenance", data.str(), gp.str(), &err)) std::cerr << "warning: " << err << "\n";
  // Figure 2: pose sweep.
  std::ostringstream d2;
  d2 << "poses ident_mm verify_mm\n";
  for (const auto& s : r.sweep) d2 << s.poses << " " << s.ident_mean_m * 1e3 << " " << s.verify_mean_m * 1e3 << "\n";
  std::ostringstream g2;
  g2 << "set title 'RLS: mean position error against the number of identification poses'\n"
     << "set xlabel 'poses'\nset ylabel 'mean position error (mm)'\nset grid\nset logscale y\n"
     << "plot datafile using 1:2 skip 1 with linespoints title 'identification (poses used)', datafile using 1:3 skip 1 "
        "with linespoints title 'verification (50 other poses)', "
     << r.noise_floor_m * 1e3 << " with lines dt 2 lc 'black' title 'noise floor'\n";
  if (!renderGnuplot(dir, "pose_sweep", d2.str(), g2.str(), &err)) std::cerr << "warning: " << err << "\n";
  // Figure 3: residuals, the a-posteriori error on each update's own identification poses (against the verification
  // error on poses it did not use: the gap is what over-fitting would show).
  std::ostringstream d3, g3;
  d3 << "group";
  for (const auto* m : runs) d3 << " \"" << m->mode << " " << runLabel(*m) << " " << m->updated_poses << "\"";
  d3 << "\n";
  for (size_t g = 0; g < groups; ++g) {
    d3 << g;
    for (const auto* m : runs) d3 << " " << m->groups[g].ident_after_m * 1e3;
    d3 << "\n";
  }
  g3 << "set title 'Residual after each update on its own identification poses (a-posteriori)'\n"
     << "set xlabel 'group (2 h apart)'\nset ylabel 'mean position residual (mm)'\nset grid\nset xtics 1\n"
     << "set key outside right\nset logscale y\n"
     << "plot for [c=2:" << 1 + runs.size() << "] datafile using 1:c with linespoints title columnhead(c)\n";
  if (!renderGnuplot(dir, "residuals", d3.str(), g3.str(), &err)) std::cerr << "warning: " << err << "\n";
  // Figure 4: per-joint drift of the zero offsets: the simulated robot's truth and continuous RLS (15 poses/group).
  const MaintenanceRun* rls = nullptr;
  for (const auto& m : r.maintenance)
    if (m.mode == "continuous" && m.algorithm == "rls" && !m.prior && m.forgetting == 1.0 && m.updated_poses == 15 &&
        m.pose_selection == "first")
      rls = &m;
  if (rls && rls->groups.front().joint_offsets_rad.size() > 0) {
    const auto joints = rls->groups.front().joint_offsets_rad.size();
    std::ostringstream d4, g4;
    d4 << "t_h";
    for (Eigen::Index j = 0; j < joints; ++j) d4 << " true" << j + 1 << " rls" << j + 1;
    d4 << "\n";
    const MaintenanceGroup& first = rls->groups.front();
    for (const auto& mg : rls->groups) {
      d4 << mg.t_h;
      for (Eigen::Index j = 0; j < joints; ++j)
        d4 << " " << (mg.true_joint_offsets_rad[j] - first.true_joint_offsets_rad[j]) * 180 / kPi * 1e3 << " "
           << (mg.joint_offsets_rad[j] - first.joint_offsets_rad[j]) * 180 / kPi * 1e3;
      d4 << "\n";
    }
    g4 << "set title 'Joint zero drift: truth (lines), continuous RLS with 15 poses per update (points)'\nset xlabel 'time (h)'\nset ylabel 'zero offset change (millidegrees)'\nset grid\n"
       << "set key outside right\n"
       << "names = \"";
    for (Eigen::Index j = 0; j < joints; ++j)
      g4 << (j ? " " : "") << "'"
         << (static_cast<size_t>(j) < r.joint_zero_names.size() ? r.joint_zero_names[static_cast<size_t>(j)]
                                                                 : "joint " + std::to_string(j + 1))
         << "'";
    g4 << "\"\n"
       << "plot for [j=1:" << joints << "] datafile using 1:(column(2*j)) skip 1 with lines lw 2 lc j "
          "title word(names, j).' truth', "
       << "for [j=1:" << joints << "] datafile using 1:(column(2*j+1)) skip 1 with points pt 7 ps 1.2 lc j "
          "title word(names, j).' RLS'\n";
    if (!renderGnuplot(dir, "joint_drift", d4.str(), g4.str(), &err)) std::cerr << "warning: " << err << "\n";
  }
}

}  // namespace

Runner addExperimentCommand(CLI::App& app) {
  auto args = std::make_shared<ExperimentArgs>();
  CLI::App* exp = app.add_subcommand("experiment", "Reproduce published experiments on a simulated robot");
  exp->require_subcommand(1);
  CLI::App* paper = addSubcommand(*exp, "paper");
  paper->add_option("--robot", args->robot, "robot YAML file")->check(CLI::ExistingFile)->capture_default_str();
  paper->add_option("--seed", args->seed, "seed of the simulated robot, tracker and poses")->capture_default_str();
  paper->add_option("--json", args->json_path, "write the results as JSON to this file")->check(outputFile());
  paper->add_option("--plot", args->plot_dir, "write PNG figures (gnuplot) into this directory");
  paper->add_option("--forgetting", args->forgetting, "lambda of the forgetting-factor variant")->capture_default_str();
  paper->add_option("--seeds", args->seeds,
                    "run this many random robots (seed, seed+1, ...) and print how often the targets hold")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  paper->add_option("--candidates", args->candidates,
                    "chosen-pose rows choose among N fresh reachable configurations per group instead of the "
                    "group's identification poses (0)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  paper->add_flag("--position-only", args->position_only, "use 3D position measurements instead of 6D poses");
  paper->add_flag("--quiet", args->quiet, "no progress line");
  return [args, paper]() -> int {
    if (!*paper) return 0;
    const RobotModel robot = loadRobotModel(args->robot);
    PaperExperimentConfig cfg;
    cfg.sim.seed = args->seed;
    cfg.forgetting = args->forgetting;
    cfg.selection_candidates = args->candidates;
    if (args->position_only) cfg.kind = MeasurementKind::kPosition3D;
    if (args->seeds > 1) {
      printSeedSummary(robot, cfg, args->seed, args->seeds, std::cout);
      return 0;
    }
    ProgressFn progress;
    if (!args->quiet && ::isatty(2))  // progress frames only on a terminal, not into a redirected log
      progress = [](const std::string& step, int done, int total) {
        std::fprintf(stderr, "\r[%-30s] %3d%%  %-24s", std::string(30 * done / total, '#').c_str(), 100 * done / total,
                     step.c_str());
        if (done == total) std::fprintf(stderr, "\n");
      };
    const auto r = runPaperExperiment(robot, cfg, progress);
    std::cout << "cellcal experiment paper: robot " << robot.name << ", seed " << args->seed << ", "
              << (args->position_only ? "3D position" : "6D pose") << " measurements\n\n";
    printTables(r, cfg, std::cout);
    if (!args->json_path.empty()) {
      std::ofstream(args->json_path) << toJson(r).dump(2) << "\n";
      std::cout << "JSON written to " << args->json_path << "\n";
    }
    if (!args->plot_dir.empty()) {
      writePlots(r, args->plot_dir);
      std::cout << "Figures written to " << args->plot_dir
                << "/maintenance.png, residuals.png, joint_drift.png and pose_sweep.png\n";
    }
    return 0;
  };
}

}  // namespace cellcal::cli
