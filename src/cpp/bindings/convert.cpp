#include "convert.hpp"

#include <mutex>
#include <stdexcept>
#include <unordered_set>

#include <cmath>
#include <cstring>
#include <stdexcept>

#include <eigenpy/eigenpy.hpp>

namespace stiction {
namespace python {

namespace {

struct NdArrayToPython {
  static PyObject* convert(const NdArray& a) { return bp::incref(a.array.ptr()); }
  static const PyTypeObject* get_pytype() { return &PyArray_Type; }
};
struct ReadOnlyMappingToPython {
  static PyObject* convert(const ReadOnlyMapping& m) { return bp::incref(m.proxy.ptr()); }
  static const PyTypeObject* get_pytype() { return &PyDictProxy_Type; }
};

}  // namespace

void registerArrayConverters() {
  bp::to_python_converter<NdArray, NdArrayToPython, true>();
  bp::to_python_converter<ReadOnlyMapping, ReadOnlyMappingToPython, true>();
}

NdArray readOnlyCopy(const Eigen::VectorXd& x) {
  npy_intp size = static_cast<npy_intp>(x.size());
  PyObject* array = PyArray_SimpleNew(1, &size, NPY_DOUBLE);
  if (array == nullptr) bp::throw_error_already_set();
  auto* a = reinterpret_cast<PyArrayObject*>(array);
  if (size > 0) std::memcpy(PyArray_DATA(a), x.data(), static_cast<std::size_t>(size) * sizeof(double));
  PyArray_CLEARFLAGS(a, NPY_ARRAY_WRITEABLE);
  return {bp::object(bp::handle<>(array))};
}

ReadOnlyMapping readOnlyMapping(const bp::dict& items) {
  PyObject* proxy = PyDictProxy_New(items.ptr());
  if (proxy == nullptr) bp::throw_error_already_set();
  return {bp::object(bp::handle<>(proxy))};
}

namespace {

bp::object numpy() {
  static bp::object np = bp::import("numpy");
  return np;
}

std::string str(const bp::object& x) { return bp::extract<std::string>(bp::str(x))(); }

std::string shapeOf(const bp::object& arr) { return str(arr.attr("shape")); }

// x as a float64 numpy array, or TypeError naming `name` and what it got.
bp::object asRealArray(const bp::object& x, const std::string& name, const char* expected) {
  if (x.is_none()) raiseTypeError(name + " must be " + expected + ", got None");
  if (PyUnicode_Check(x.ptr()) || PyBytes_Check(x.ptr()))
    raiseTypeError(name + " must be " + expected + ", got " + typeName(x));
  bp::object arr;
  try {
    arr = numpy().attr("asarray")(x);
  } catch (const bp::error_already_set&) {
    PyErr_Clear();
    raiseTypeError(name + " must be " + expected + ", got " + typeName(x) + " that numpy cannot read as an array");
  }
  const std::string kind = str(arr.attr("dtype").attr("kind"));
  if (kind == "c") raiseTypeError(name + " must be real, got a complex array");
  if (kind != "f" && kind != "i" && kind != "u" && kind != "b")
    raiseTypeError(name + " must be " + expected + ", got " + typeName(x) + " (numpy dtype " +
                   str(arr.attr("dtype")) + ")");
  return numpy().attr("asarray")(arr, "float64");
}

}  // namespace

void raiseTypeError(const std::string& message) {
  PyErr_SetString(PyExc_TypeError, message.c_str());
  bp::throw_error_already_set();
  throw std::logic_error("unreachable");  // throw_error_already_set never returns
}

std::string typeName(const bp::object& x) {
  if (x.is_none()) return "None";
  const std::string t = bp::extract<std::string>(x.attr("__class__").attr("__name__"))();
  if (t == "ndarray") return str(x.attr("dtype")) + " ndarray of shape " + shapeOf(x);
  return t;
}

double toDouble(const bp::object& x, const std::string& name) {
  PyObject* p = x.ptr();
  const bool complex_valued =
      PyComplex_Check(p) || (!PyFloat_Check(p) && !PyLong_Check(p) && PyObject_HasAttrString(p, "dtype") &&
                             bp::extract<bool>(numpy().attr("iscomplexobj")(x))());
  if (x.is_none() || PyBool_Check(p) || PyUnicode_Check(p) || PyBytes_Check(p) || complex_valued)
    raiseTypeError(name + " must be a real number, got " + typeName(x));
  if (PyObject_HasAttrString(p, "ndim") && bp::extract<long>(x.attr("ndim"))() != 0)
    raiseTypeError(name + " must be a real number, got " + typeName(x));
  PyObject* f = PyNumber_Float(p);
  if (f == nullptr) {
    PyErr_Clear();
    raiseTypeError(name + " must be a real number, got " + typeName(x));
  }
  const double v = PyFloat_AsDouble(f);
  Py_DECREF(f);
  return v;
}

long toInteger(const bp::object& x, const std::string& name) {
  PyObject* p = x.ptr();
  if (x.is_none() || PyBool_Check(p)) raiseTypeError(name + " must be an integer, got " + typeName(x));
  PyObject* i = PyNumber_Index(p);  // int and numpy integers; not float, not str
  if (i == nullptr) {
    PyErr_Clear();
    raiseTypeError(name + " must be an integer, got " + typeName(x) + (PyFloat_Check(p) ? " " + str(x) : ""));
  }
  const long v = PyLong_AsLong(i);
  Py_DECREF(i);
  if (v == -1 && PyErr_Occurred()) {
    PyErr_Clear();
    throw std::invalid_argument(name + " is out of range");
  }
  return v;
}

bool toBool(const bp::object& x, const std::string& name) {
  PyObject* p = x.ptr();
  if (PyBool_Check(p)) return p == Py_True;
  if (PyObject_IsInstance(p, bp::object(numpy().attr("bool_")).ptr()) == 1) return PyObject_IsTrue(p) == 1;
  raiseTypeError(name + " must be True or False, got " + typeName(x));
}

std::string toStringArg(const bp::object& x, const std::string& name) {
  if (!PyUnicode_Check(x.ptr())) raiseTypeError(name + " must be a str, got " + typeName(x));
  return bp::extract<std::string>(x)();
}

Eigen::VectorXd toVector(const bp::object& x, const std::string& name, Eigen::Index expected) {
  const std::string what = expected >= 0 ? "a 1-D array of " + std::to_string(expected) + " floats"
                                         : std::string("a 1-D array of floats");
  bp::object arr = asRealArray(x, name, what.c_str());
  const long ndim = bp::extract<long>(arr.attr("ndim"))();
  if (ndim != 1)
    throw std::invalid_argument(name + " must be " + what + ", got an array of shape " + shapeOf(arr));
  const long n = bp::extract<long>(arr.attr("size"))();
  if (expected >= 0 && n != expected)
    throw std::invalid_argument(name + " needs " + std::to_string(expected) + " entries, got " + std::to_string(n));
  return bp::extract<Eigen::VectorXd>(arr)();
}

Eigen::MatrixXd toMatrix(const bp::object& x, const std::string& name) {
  bp::object arr = asRealArray(x, name, "a 2-D array of floats");
  const long ndim = bp::extract<long>(arr.attr("ndim"))();
  if (ndim != 2)
    throw std::invalid_argument(name + " must be a 2-D array of floats, got an array of shape " + shapeOf(arr));
  return bp::extract<Eigen::MatrixXd>(arr)();
}

template <>
double fromPython<double>(const bp::object& x, const std::string& name) {
  return toDouble(x, name);
}
template <>
int fromPython<int>(const bp::object& x, const std::string& name) {
  const long v = toInteger(x, name);
  if (v < -2147483647L || v > 2147483647L) throw std::invalid_argument(name + " is out of range");
  return static_cast<int>(v);
}
template <>
long fromPython<long>(const bp::object& x, const std::string& name) {
  return toInteger(x, name);
}
template <>
unsigned long fromPython<unsigned long>(const bp::object& x, const std::string& name) {
  const long v = toInteger(x, name);
  if (v < 0) throw std::invalid_argument(name + " must be >= 0, got " + std::to_string(v));
  return static_cast<unsigned long>(v);
}
template <>
bool fromPython<bool>(const bp::object& x, const std::string& name) {
  return toBool(x, name);
}
template <>
std::string fromPython<std::string>(const bp::object& x, const std::string& name) {
  return toStringArg(x, name);
}
template <>
Eigen::Vector3d fromPython<Eigen::Vector3d>(const bp::object& x, const std::string& name) {
  const Eigen::VectorXd v = toVector(x, name, 3);
  if (!v.allFinite()) throw std::invalid_argument(name + " has NaN or infinite entries");
  return v;
}

namespace {
std::mutex in_use_mutex;
std::unordered_set<const void*> in_use;
}  // namespace

InUse::InUse(const void* object, const char* what) : object_(object) {
  std::lock_guard<std::mutex> lock(in_use_mutex);
  if (!in_use.insert(object).second)
    throw std::runtime_error(std::string(what) +
                             " is in use by another thread (each thread needs its own: a Simulator, or a "
                             "Solver / Formulation object)");
}

InUse::~InUse() {
  std::lock_guard<std::mutex> lock(in_use_mutex);
  in_use.erase(object_);
}

}  // namespace python
}  // namespace stiction
