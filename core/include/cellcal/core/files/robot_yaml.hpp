// Loading a RobotModel from the robot YAML file (format in docs/robot-file.md).
// Errors are thrown as ConfigError whose message starts with "<file>:<line>:<column>: <field>: ".
#pragma once

#include <stdexcept>
#include <string>

#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

RobotModel loadRobotModel(const std::string& path);
// `source` names the text in error messages (a file name, or e.g. "<test>").
RobotModel parseRobotModel(const std::string& yaml_text, const std::string& source);

}  // namespace cellcal
