// cellcal_rsi_bridge: a KUKA controller's RSI stream answered inside its cycle with the cell's calibrations. The
// process: rsi_bridge.hpp.
#include "rsi_bridge.hpp"

using namespace cellcal::components;

int main(int argc, char** argv) {
  return componentMain<RsiBridge>("cellcal_rsi_bridge", argc, argv, [](CLI::App& app, RsiBridge::Options& o) {
    addCommonOptions(app, o.process);
    app.add_option("--robot", o.robot, "the cell file's robot this controller drives (default: its only one)");
    app.add_option("--listen", o.listen, "IPv4 address and UDP port the controller's RSI ETHERNET object sends to")
        ->capture_default_str();
    app.add_option("--controller", o.controller,
                   "the controller's IPv4 address; datagrams from any other address are dropped and counted")
        ->required();
    app.add_option("--sensor-type", o.sensor_type, "the Type of the answers (<Sen Type=...>), as RSI is configured")
        ->capture_default_str();
    app.add_option("--cycle-ms", o.cycle_ms, "RSI's cycle (4: IPO_FAST; 12)")->capture_default_str();
    app.add_option("--max-correction-deg", o.max_correction_deg,
                   "largest axis correction sent (default: the cell file's compensation.max_joint_correction_deg, "
                   "above which the compensator holds by itself); AXISCORR's limits at or above it");
    app.add_option("--rt-priority", o.rt_priority,
                   "run the cycle's thread SCHED_FIFO at this priority (1-99; needs root or CAP_SYS_NICE)");
    app.add_option("--cpu", o.cpu, "pin the cycle's thread to this core");
    app.add_option("--duration-s", o.duration_s, "stop after this many seconds (0: run until SIGINT/SIGTERM)");
    app.add_flag("--pass-through", o.pass_through,
                 "answer every readable packet with a zero correction, no compensator: the floor of the transport and "
                 "the host for a bench, never for a robot");
  });
}
