# core's source files, one list: the library (core/CMakeLists.txt) and the fuzz build (tests/fuzz) both take it, so a
# file added here is in both. Paths relative to core/.
set(CELLCAL_CORE_SOURCES
  # model/: the robot and its kinematics
  src/model/se3.cpp
  src/model/robot_model.cpp
  src/model/kinematics.cpp
  src/model/inverse_kinematics.cpp
  src/model/model_extension.cpp
  src/model/calibrated_model.cpp              # what a calibration identified, as one value
  src/model/causes/registry.cpp                # one file per cause (cause_list.hpp), registered once
  src/model/causes/joint_compliance.cpp
  src/model/causes/thermal_drift.cpp
  src/model/causes/cyclic_transmission.cpp
  src/model/causes/joint_scale.cpp
  src/model/causes/backlash.cpp
  src/model/causes/link_deflection.cpp
  src/model/causes/frame_drift.cpp
  # identification/: from measurements to parameters, and what they leave
  src/identification/observation.cpp
  src/identification/model_error.cpp
  src/identification/identifiability.cpp
  src/identification/gauss_newton.cpp
  src/identification/levenberg_marquardt.cpp   # Ceres solver headers: here and in residual_map_fit.cpp (no autodiff)
  src/identification/rls.cpp
  src/identification/statistics.cpp
  src/identification/outliers.cpp
  src/identification/prediction.cpp
  src/identification/setups.cpp
  src/identification/pose_selection.cpp
  src/identification/pose_plan.cpp
  src/identification/residual_map.cpp
  src/identification/residual_map_fit.cpp
  src/identification/registration.cpp
  src/identification/setup_change.cpp          # a set-up change inside one file, from the residuals' structure
  src/identification/controller_check.cpp      # a controller's own poses against a model (robot check)
  src/identification/extended_fit.cpp
  src/identification/diagnosis.cpp
  src/identification/diagnosis_regions.cpp
  src/identification/extension_transfer.cpp
  src/identification/beyond_range.cpp
  src/identification/diagnosis_drift.cpp
  # files/: the robot file, the cell file, measurement files
  src/files/robot_yaml.cpp
  src/files/cell_config.cpp
  src/files/measurement_csv.cpp
  src/files/urdf.cpp                           # the only TU with liburdfdom and TinyXML
  src/files/export.cpp                         # write(model, CalibratedModel, format): urdf, ur-kinematics, dh-table
  # campaign/: a measurement file's campaign, whole (split, registration, fit, figures, verdict)
  src/campaign/campaign_input.cpp
  src/campaign/campaign.cpp
  src/campaign/campaign_setups.cpp
  # engine/: the calibration engine of one robot (no DDS, no threads), pairing, compensation
  src/engine/pairing.cpp
  src/engine/outlier_gate.cpp
  src/engine/work_configurations.cpp           # where the cell works: the configurations health is judged at
  src/engine/file_probation.cpp
  src/engine/file_trial.cpp                    # a calibration file judged against its nominal kinematics
  src/engine/input_watch.cpp
  src/engine/calibration_engine.cpp
  src/engine/calibration_start.cpp             # the estimate and prior from a calibrated robot file
  src/engine/health.cpp                        # the health rule
  src/engine/state_file.cpp
  src/engine/state_journal.cpp
  src/engine/compensation.cpp
  src/engine/servo.cpp
  src/engine/pose_requests.cpp
  # servo/: compensation inside a controller's cycle (no allocation, no lock), versions handed over wait-free
  src/servo/realtime_compensator.cpp
  src/servo/rsi_xml.cpp                        # KUKA RSI's <Rob> and <Sen> packets, without allocation
  src/servo/rsi_session.cpp                    # one RSI connection's packets answered by the compensator
  # sim/: a simulated robot and tracker
  src/sim/simulation.cpp
  # accuracy/: ISO 9283 figures from measured poses, and the standard's test cube and poses
  src/accuracy/iso9283.cpp
  src/accuracy/iso9283_test.cpp
  src/accuracy/iso9283_plan.cpp
)
