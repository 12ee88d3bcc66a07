// Python arguments to C++ values, with errors that name the argument: TypeError
// for the wrong kind of object (None, str, complex, a list of the wrong things),
// ValueError for the wrong shape or range. Every binding takes bp::object and
// converts through these, so a caller never sees Boost.Python's "did not match
// C++ signature" text. Lists of numbers are accepted where an array is (as numpy does).
#pragma once

#include <string>
#include <vector>

#include <boost/mpl/vector.hpp>
#include <boost/python.hpp>
#include <Eigen/Core>

#include "stiction/formulation.hpp"

namespace stiction {
namespace python {

namespace bp = boost::python;

/// A Python list of the elements of a C++ container (each converted by Boost.Python).
template <typename Container>
bp::list pyList(const Container& items) {
  bp::list out;
  for (const auto& item : items) out.append(item);
  return out;
}

/// A numpy array made by the bindings (a view or a read-only copy), returned as it is; a type of its
/// own so that the signatures in the docstrings (and the stubs made from them) say numpy.ndarray.
struct NdArray {
  bp::object array;
};
/// A read-only float64 numpy copy of a vector (one allocation and a memcpy): a write into it raises
/// instead of being silently lost.
NdArray readOnlyCopy(const Eigen::VectorXd& x);
/// A read-only view of a dict (types.MappingProxyType): item assignment raises TypeError. The
/// signatures say mappingproxy.
struct ReadOnlyMapping {
  bp::object proxy;
};
ReadOnlyMapping readOnlyMapping(const bp::dict& items);
/// The to-Python converters of NdArray and ReadOnlyMapping (module.cpp, before any expose function).
void registerArrayConverters();

/// Raise TypeError(message) (never returns).
[[noreturn]] void raiseTypeError(const std::string& message);

/// Python's repr-like short description of x's type, e.g. "str", "NoneType", "complex ndarray".
std::string typeName(const bp::object& x);

/// A real number (int, float, numpy scalar, 0-d array). bool, None, str and complex: TypeError.
double toDouble(const bp::object& x, const std::string& name);
/// An integer (int or numpy integer; not bool, not float).
long toInteger(const bp::object& x, const std::string& name);
bool toBool(const bp::object& x, const std::string& name);
std::string toStringArg(const bp::object& x, const std::string& name);

/// A 1-D real array (numpy array or a list of numbers), `expected` entries unless -1.
Eigen::VectorXd toVector(const bp::object& x, const std::string& name, Eigen::Index expected = -1);
/// A 2-D real array (numpy array or a list of rows).
Eigen::MatrixXd toMatrix(const bp::object& x, const std::string& name);

/// x as a C++ object of class T exposed to Python (e.g. a stiction.Constraint), or TypeError
/// "name must be a <what>, got <type>".
template <typename T>
T& toObject(const bp::object& x, const std::string& name, const char* what) {
  bp::extract<T&> e(x);
  if (!e.check()) raiseTypeError(name + " must be a " + what + ", got " + typeName(x));
  return e();
}

/// A value of an enum exposed with bp::enum_ (converted by value, not by reference).
template <typename E>
E toEnum(const bp::object& x, const std::string& name, const char* what) {
  bp::extract<E> e(x);
  if (!e.check()) raiseTypeError(name + " must be a " + what + ", got " + typeName(x));
  return e();
}

/// A list or tuple of T ("name[i] must be a <what>").
template <typename T>
std::vector<T> toList(const bp::object& seq, const std::string& name, const char* what) {
  if (!PyList_Check(seq.ptr()) && !PyTuple_Check(seq.ptr()))
    raiseTypeError(name + " must be a list of " + what + ", got " + typeName(seq));
  std::vector<T> out;
  const long n = bp::len(seq);
  out.reserve(n);
  for (long i = 0; i < n; ++i) out.push_back(toObject<T>(seq[i], name + "[" + std::to_string(i) + "]", what));
  return out;
}

/// Convert a Python value to T with the functions above (T: double, int, long, bool, std::string,
/// Eigen::Vector3d).
template <typename T>
T fromPython(const bp::object& x, const std::string& name);

template <> double fromPython<double>(const bp::object& x, const std::string& name);
template <> int fromPython<int>(const bp::object& x, const std::string& name);
template <> long fromPython<long>(const bp::object& x, const std::string& name);
template <> unsigned long fromPython<unsigned long>(const bp::object& x, const std::string& name);
template <> bool fromPython<bool>(const bp::object& x, const std::string& name);
template <> FormulationSettings fromPython<FormulationSettings>(const bp::object& x, const std::string& name);
template <> std::string fromPython<std::string>(const bp::object& x, const std::string& name);
template <> Eigen::Vector3d fromPython<Eigen::Vector3d>(const bp::object& x, const std::string& name);

/// A read-write property `name` for the data member `member` of C whose setter converts
/// through fromPython (so `settings.dt = "x"` raises TypeError naming dt).
template <typename C, typename T, typename Class>
void checkedMember(Class& cls, const char* name, T C::*member, const char* doc = nullptr) {
  const std::string label = name;
  auto get = [member](const C& c) { return c.*member; };
  auto set = [member, label](C& c, const bp::object& x) { c.*member = fromPython<T>(x, label); };
  cls.add_property(name, bp::make_function(get, bp::default_call_policies(), boost::mpl::vector<T, const C&>()),
                   bp::make_function(set, bp::default_call_policies(),
                                     boost::mpl::vector<void, C&, const bp::object&>()),
                   doc);
}

/// Releases the GIL for its lifetime (long C++ work: rollouts, solves), so Python threads run
/// meanwhile. Nothing inside may touch a Python object.
class ReleaseGil {
 public:
  ReleaseGil() : state_(PyEval_SaveThread()) {}
  ~ReleaseGil() { PyEval_RestoreThread(state_); }
  ReleaseGil(const ReleaseGil&) = delete;
  ReleaseGil& operator=(const ReleaseGil&) = delete;

 private:
  PyThreadState* state_;
};

/// Marks a C++ object (a SimulatorData, a solver's workspace) as used by one call while the GIL
/// is released: a second thread reaching it meanwhile gets a RuntimeError naming it instead of a
/// data race. Taken with the GIL held.
class InUse {
 public:
  InUse(const void* object, const char* what);
  ~InUse();
  InUse(const InUse&) = delete;
  InUse& operator=(const InUse&) = delete;

 private:
  const void* object_;
};

}  // namespace python
}  // namespace stiction

