// CDR round trip of a generated topic type (serialize, then deserialize into a fresh sample), for the dds tests.
#pragma once

#include <gtest/gtest.h>

#include <fastdds/rtps/common/SerializedPayload.h>

namespace cellcal::test {

template <typename PubSubType, typename T>
T roundTrip(const T& in) {
  PubSubType type;
  eprosima::fastrtps::rtps::SerializedPayload_t payload(type.getSerializedSizeProvider(const_cast<T*>(&in))());
  EXPECT_TRUE(type.serialize(const_cast<T*>(&in), &payload));
  T out;
  EXPECT_TRUE(type.deserialize(&payload, &out));
  return out;
}

}  // namespace cellcal::test
