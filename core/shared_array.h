// shared_array.h — a std::vector whose copies share their values until one of them is
// written: a simulation's per-grain arrays (InstancedGrainsDesc: gigabytes at 10^8 grains)
// pass through descriptions that the front ends, toRenderSpace and the scene build copy
// whole, and the grid keeps them; each of those copies costs nothing per grain.
//
// Contract.
//  - SharedArray<T> reads as a const std::vector<T> (and converts to one). Copying shares
//    the values (constant time); the shared values are never written.
//  - A non-const access (operator[], data(), begin(), end(), back(), resize, assign,
//    push_back, ... and vec()) first makes the values this array's own when another
//    array shares them (a copy: copy-on-write), so writing through it changes it alone. Read
//    through a const reference (or const_cast-free std::as_const) to avoid that copy.
//  - sharesWith(b): the same values object (equal without looking at them).
//  - stamp(): a number naming these values while they stay unwritten (0 for none), unique in
//    the process: copies share it, any non-const access (a possible write) drops it and the
//    next stamp() draws a new one. Equal non-zero stamps, equal values: what was checked
//    once on an array can be trusted while its stamp holds (validateInstancedGrains). A
//    write through a reference or pointer taken before that stamp() is not seen: take
//    them anew after a check.
//  - Thread safety as a std::vector's: concurrent const reads; a write to one array while
//    another thread reads or copies the same array object is a race (copies of it are other
//    objects: writing one while another is read is safe).
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <utility>
#include <vector>

namespace granular {

template <class T>
class SharedArray {
 public:
  using value_type = T;
  using size_type = size_t;
  using iterator = typename std::vector<T>::iterator;
  using const_iterator = typename std::vector<T>::const_iterator;

  SharedArray() = default;
  SharedArray(const SharedArray& o) : p_(o.p_), stamp_(o.p_ ? o.stamp() : 0) {}
  SharedArray(SharedArray&& o) noexcept : p_(std::move(o.p_)), stamp_(o.stamp_.exchange(0)) {}
  SharedArray& operator=(const SharedArray& o) {
    if (this != &o) {
      p_ = o.p_;
      stamp_.store(o.p_ ? o.stamp() : 0, std::memory_order_relaxed);
    }
    return *this;
  }
  SharedArray& operator=(SharedArray&& o) noexcept {
    if (this != &o) {
      p_ = std::move(o.p_);
      stamp_.store(o.stamp_.exchange(0), std::memory_order_relaxed);
    }
    return *this;
  }
  SharedArray(std::vector<T> v) : p_(v.empty() ? nullptr : std::make_shared<std::vector<T>>(std::move(v))) {}
  SharedArray(std::initializer_list<T> v) : SharedArray(std::vector<T>(v)) {}
  SharedArray& operator=(std::vector<T> v) { return *this = SharedArray(std::move(v)); }
  SharedArray& operator=(std::initializer_list<T> v) { return *this = SharedArray(std::vector<T>(v)); }

  // Reading.
  const std::vector<T>& get() const { return p_ ? *p_ : empty_(); }
  operator const std::vector<T>&() const { return get(); }
  size_t size() const { return p_ ? p_->size() : 0; }
  bool empty() const { return size() == 0; }
  const T& operator[](size_t i) const { return (*p_)[i]; }
  const T* data() const { return get().data(); }
  const_iterator begin() const { return get().begin(); }
  const_iterator end() const { return get().end(); }
  const T& front() const { return p_->front(); }
  const T& back() const { return p_->back(); }
  bool sharesWith(const SharedArray& b) const { return p_ == b.p_; }
  uint64_t stamp() const {
    if (!p_) return 0;
    uint64_t s = stamp_.load(std::memory_order_relaxed);
    if (s) return s;
    const uint64_t fresh = nextStamp().fetch_add(1, std::memory_order_relaxed);
    return stamp_.compare_exchange_strong(s, fresh, std::memory_order_relaxed) ? fresh : s;
  }
  friend bool operator==(const SharedArray& a, const SharedArray& b) { return a.p_ == b.p_ || a.get() == b.get(); }
  friend bool operator!=(const SharedArray& a, const SharedArray& b) { return !(a == b); }

  // Writing: this array's own values first (copy-on-write).
  std::vector<T>& vec() {
    if (stamp_.load(std::memory_order_relaxed)) stamp_.store(0, std::memory_order_relaxed);
    if (!p_) p_ = std::make_shared<std::vector<T>>();
    else if (p_.use_count() > 1) p_ = std::make_shared<std::vector<T>>(*p_);
    return *p_;
  }
  T& operator[](size_t i) { return vec()[i]; }
  T* data() { return vec().data(); }
  iterator begin() { return vec().begin(); }
  iterator end() { return vec().end(); }
  T& front() { return vec().front(); }
  T& back() { return vec().back(); }
  void resize(size_t n) { vec().resize(n); }
  void resize(size_t n, const T& v) { vec().resize(n, v); }
  void reserve(size_t n) { vec().reserve(n); }
  void clear() {
    p_.reset();
    stamp_.store(0, std::memory_order_relaxed);
  }
  void push_back(const T& v) { vec().push_back(v); }
  template <class... A>
  T& emplace_back(A&&... a) { return vec().emplace_back(std::forward<A>(a)...); }
  void pop_back() { vec().pop_back(); }
  template <class... A>
  void assign(A&&... a) { vec().assign(std::forward<A>(a)...); }
  template <class... A>
  iterator insert(const_iterator pos, A&&... a) {
    const auto k = pos - get().begin();  // the position survives the copy-on-write
    std::vector<T>& v = vec();
    return v.insert(v.begin() + k, std::forward<A>(a)...);
  }

 private:
  static const std::vector<T>& empty_() {
    static const std::vector<T> none;
    return none;
  }
  static std::atomic<uint64_t>& nextStamp() {
    static std::atomic<uint64_t> next{1};
    return next;
  }
  std::shared_ptr<std::vector<T>> p_;
  mutable std::atomic<uint64_t> stamp_{0};
};

}  // namespace granular
