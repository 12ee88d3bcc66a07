// The compiled core: stiction._core (Boost.Python + eigenpy, like Pinocchio, so
// numpy arrays and Pinocchio's own Python objects pass straight through).
#include <boost/python.hpp>
#include <eigenpy/eigenpy.hpp>

#include "convert.hpp"
#include "expose.hpp"

BOOST_PYTHON_MODULE(_core) {
  eigenpy::enableEigenPy();
  boost::python::scope().attr("__doc__") =
      "Compiled core of stiction: the contact problem of eq. 65 and its solvers.";
  stiction::python::registerArrayConverters();  // (first: the signatures of every function name their types)
  stiction::python::exposeProblem();
  stiction::python::exposeSolver();
  stiction::python::exposeSimulator();
}
