#ifndef TESTED_CPP__RING_BUFFER_HPP_
#define TESTED_CPP__RING_BUFFER_HPP_

#include <array>
#include <cstddef>

namespace tested_cpp
{

// The last N samples of a sensor; the oldest is overwritten when full.
template<typename T, std::size_t N>
class RingBuffer
{
public:
  void push(const T & value)
  {
    data_[(start_ + size_) % N] = value;
    if (size_ < N) {
      ++size_;
    } else {
      start_ = (start_ + 1) % N;
    }
  }

  std::size_t size() const {return size_;}

  // The I-th oldest sample.
  const T & at(std::size_t i) const {return data_[(start_ + i) % N];}

private:
  std::array<T, N> data_{};
  std::size_t start_ = 0;
  std::size_t size_ = 0;
};

}  // namespace tested_cpp

#endif  // TESTED_CPP__RING_BUFFER_HPP_
