#include <gtest/gtest.h>

#include "tested_cpp/ring_buffer.hpp"

TEST(RingBuffer, KeepsSamplesInOrder)
{
  tested_cpp::RingBuffer<int, 3> buffer;
  buffer.push(1);
  buffer.push(2);
  ASSERT_EQ(buffer.size(), 2u);
  EXPECT_EQ(buffer.at(0), 1);
  EXPECT_EQ(buffer.at(1), 2);
}

TEST(RingBuffer, OverwritesTheOldestWhenFull)
{
  tested_cpp::RingBuffer<int, 2> buffer;
  for (int i = 1; i <= 3; ++i) {
    buffer.push(i);
  }
  ASSERT_EQ(buffer.size(), 2u);
  EXPECT_EQ(buffer.at(0), 2);
  EXPECT_EQ(buffer.at(1), 3);
}
