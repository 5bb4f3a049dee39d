// A vector stored in fixed-size chunks that copies share: a copy costs one pointer per chunk, and
// writing to a shared chunk first copies that chunk alone.  The pipeline keeps one as the working
// copy of what its snapshots show and hands each new Snapshot a copy, so a snapshot after an
// update that moved k keyframes costs O(k + size / kChunkSize), not O(size), and every published
// snapshot stays immutable (a chunk it holds is never written again).
#pragma once

#include <cstddef>
#include <initializer_list>
#include <iterator>
#include <memory>
#include <stdexcept>
#include <vector>

namespace toro_ros {

template <class T, std::size_t kChunkSize = 1024>
class ChunkedVector {
  static_assert(kChunkSize > 0, "chunks hold at least one element");

 public:
  using value_type = T;
  using size_type = std::size_t;

  class const_iterator {
   public:
    using iterator_category = std::forward_iterator_tag;
    using value_type = T;
    using difference_type = std::ptrdiff_t;
    using pointer = const T*;
    using reference = const T&;
    const_iterator() = default;
    const T& operator*() const { return (*v_)[i_]; }
    const T* operator->() const { return &(*v_)[i_]; }
    const_iterator& operator++() {
      ++i_;
      return *this;
    }
    const_iterator operator++(int) {
      const_iterator old = *this;
      ++i_;
      return old;
    }
    bool operator==(const const_iterator& o) const { return i_ == o.i_; }
    bool operator!=(const const_iterator& o) const { return i_ != o.i_; }

   private:
    friend class ChunkedVector;
    const_iterator(const ChunkedVector* v, std::size_t i) : v_(v), i_(i) {}
    const ChunkedVector* v_ = nullptr;
    std::size_t i_ = 0;
  };
  using iterator = const_iterator;  // elements change through set() only (copy on write)

  ChunkedVector() = default;
  ChunkedVector(std::initializer_list<T> values) {
    for (const T& v : values) push_back(v);
  }
  // A copy shares every chunk the source will not write in place again, and copies the others
  // (those the source created or copied since it was last shared), so neither can see the other's
  // later writes.  Reading the source's flags only: copying a published (const) one is safe from
  // any thread.
  ChunkedVector(const ChunkedVector& o) : size_(o.size_), chunks_(o.chunks_), writable_(o.writable_) {
    for (std::size_t k = 0; k < chunks_.size(); ++k)
      if (writable_[k]) chunks_[k] = std::make_shared<Chunk>(*chunks_[k]);
  }
  ChunkedVector(ChunkedVector&& o) noexcept
      : size_(o.size_), chunks_(std::move(o.chunks_)), writable_(std::move(o.writable_)) {
    o.clear();
  }
  ChunkedVector& operator=(const ChunkedVector& o) {
    if (this != &o) *this = ChunkedVector(o);
    return *this;
  }
  ChunkedVector& operator=(ChunkedVector&& o) noexcept {
    if (this != &o) {
      size_ = o.size_;
      chunks_ = std::move(o.chunks_);
      writable_ = std::move(o.writable_);
      o.clear();
    }
    return *this;
  }

  // A copy sharing every chunk; afterwards this vector copies a chunk before writing to it.  The
  // cheap way to publish the working copy.
  ChunkedVector share() {
    for (std::size_t k = 0; k < writable_.size(); ++k) writable_[k] = 0;
    return ChunkedVector(*this);
  }

  std::size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  const T& operator[](std::size_t i) const { return (*chunks_[i / kChunkSize])[i % kChunkSize]; }
  const T& at(std::size_t i) const {
    if (i >= size_) throw std::out_of_range("ChunkedVector::at");
    return (*this)[i];
  }
  const T& front() const { return (*this)[0]; }
  const T& back() const { return (*this)[size_ - 1]; }
  const_iterator begin() const { return const_iterator(this, 0); }
  const_iterator end() const { return const_iterator(this, size_); }

  void set(std::size_t i, const T& value) { (*writableChunk(i / kChunkSize))[i % kChunkSize] = value; }
  void push_back(const T& value) {
    if (size_ % kChunkSize == 0) {
      chunks_.push_back(std::make_shared<Chunk>());
      chunks_.back()->reserve(kChunkSize);
      writable_.push_back(1);
    }
    writableChunk(chunks_.size() - 1)->push_back(value);
    ++size_;
  }
  void clear() {
    size_ = 0;
    chunks_.clear();
    writable_.clear();
  }

  // Whether element i of this and of `other` are one object (a shared chunk): for tests.
  bool sharesElementWith(const ChunkedVector& other, std::size_t i) const {
    return i < size_ && i < other.size_ && &(*this)[i] == &other[i];
  }

 private:
  using Chunk = std::vector<T>;

  Chunk* writableChunk(std::size_t k) {
    if (!writable_[k]) {
      auto copy = std::make_shared<Chunk>();
      copy->reserve(kChunkSize);
      copy->insert(copy->end(), chunks_[k]->begin(), chunks_[k]->end());
      chunks_[k] = std::move(copy);
      writable_[k] = 1;
    }
    return chunks_[k].get();
  }

  std::size_t size_ = 0;
  std::vector<std::shared_ptr<Chunk>> chunks_;
  // Per chunk: created or copied by this vector since it was last shared, so no other vector holds
  // it and it may be written in place.
  std::vector<char> writable_;
};

}  // namespace toro_ros
