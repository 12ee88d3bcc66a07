#include <boost/python.hpp>
#include <eigenpy/eigenpy.hpp>

#include "convert.hpp"
#include "expose.hpp"
#include "stiction/contact_problem.hpp"
#include "stiction/delassus.hpp"

namespace bp = boost::python;

namespace stiction {
namespace python {

namespace {

/// A scipy.sparse matrix as an Eigen compressed-column matrix (its CSC arrays copied).
Eigen::SparseMatrix<double> toSparse(const bp::object& A) {
  const bp::object csc = A.attr("tocsc")();
  const bp::tuple shape = bp::extract<bp::tuple>(bp::object(csc.attr("shape")));
  const long rows = bp::extract<long>(shape[0]), cols = bp::extract<long>(shape[1]);
  if (rows != cols)
    throw std::invalid_argument("ContactProblem: A must be square, got " + std::to_string(rows) + "x" +
                                std::to_string(cols));
  const bp::object np = bp::import("numpy");
  const Eigen::VectorXd data = toVector(np.attr("asarray")(bp::object(csc.attr("data")), "float64"), "ContactProblem: A.data");
  const Eigen::VectorXd indices = toVector(np.attr("asarray")(bp::object(csc.attr("indices")), "float64"), "ContactProblem: A.indices");
  const Eigen::VectorXd indptr = toVector(np.attr("asarray")(bp::object(csc.attr("indptr")), "float64"), "ContactProblem: A.indptr");
  if (indptr.size() != cols + 1 || indices.size() != data.size())
    throw std::invalid_argument("ContactProblem: A is a malformed sparse matrix");
  std::vector<Eigen::Triplet<double>> entries;
  entries.reserve(static_cast<std::size_t>(data.size()));
  for (long j = 0; j < cols; ++j)
    for (long k = static_cast<long>(indptr[j]); k < static_cast<long>(indptr[j + 1]); ++k) {
      const long i = static_cast<long>(indices[k]);
      if (i < 0 || i >= rows) throw std::invalid_argument("ContactProblem: A has a row index out of range");
      entries.emplace_back(static_cast<int>(i), static_cast<int>(j), data[k]);
    }
  Eigen::SparseMatrix<double> out(rows, cols);
  out.setFromTriplets(entries.begin(), entries.end());  // duplicates summed, as scipy does
  return out;
}

std::shared_ptr<ContactProblem> makeProblem(const bp::object& A, const bp::object& b, const bp::object& constraints,
                                            const bp::object& asymmetry_tolerance) {
  if (constraints.is_none()) raiseTypeError("ContactProblem: constraints is required (a list of stiction.Constraint)");
  std::shared_ptr<DelassusOperator> op;
  if (PyObject_HasAttrString(A.ptr(), "tocsc") && PyObject_HasAttrString(A.ptr(), "nnz")) {
    op = std::make_shared<SparseDelassus>(toSparse(A));  // a scipy.sparse matrix: kept sparse
  } else {
    op = std::make_shared<DenseDelassus>(toMatrix(A, "ContactProblem: A"));
  }
  Eigen::VectorXd bv = toVector(b, "ContactProblem: b");
  std::vector<Constraint> cons = toList<Constraint>(constraints, "ContactProblem: constraints", "stiction.Constraint");
  const double tol = toDouble(asymmetry_tolerance, "ContactProblem: asymmetry_tolerance");
  if (!(tol >= 0.0)) throw std::invalid_argument("ContactProblem: asymmetry_tolerance must be >= 0");
  return std::make_shared<ContactProblem>(std::move(op), std::move(bv), std::move(cons), tol);
}

// For the tests: the operator a problem would hold for A: dense, scipy.sparse (scattered), or
// scipy.sparse declared symmetric (gathered by columns, as the simulator's A).
std::shared_ptr<DelassusOperator> testOperator(const bp::object& A, bool symmetric, const std::string& what) {
  if (PyObject_HasAttrString(A.ptr(), "tocsc") && PyObject_HasAttrString(A.ptr(), "nnz"))
    return std::make_shared<SparseDelassus>(toSparse(A), symmetric);
  return std::make_shared<DenseDelassus>(toMatrix(A, what.c_str()));
}

// For the tests: the verdict's compensated residual A x - b (compensated.hpp).
Eigen::VectorXd compensatedResidualOf(const bp::object& A, const bp::object& x, const bp::object& b,
                                      bool symmetric) {
  const auto op = testOperator(A, symmetric, "_compensated_residual: A");
  const Eigen::VectorXd xv = toVector(x, "_compensated_residual: x", op->rows());
  const Eigen::VectorXd bv = toVector(b, "_compensated_residual: b", op->rows());
  Eigen::VectorXd y(op->rows());
  op->compensatedResidual(xv, bv, y);
  return y;
}

// For the tests: the operator's double products (multiply, absMultiply, multiplyWithAbs's two),
// to compare the vector kernels' with the portable loops'.
bp::tuple operatorProductsOf(const bp::object& A, const bp::object& x, bool symmetric) {
  const auto op = testOperator(A, symmetric, "_operator_products: A");
  const Eigen::VectorXd xv = toVector(x, "_operator_products: x", op->rows());
  Eigen::VectorXd y(op->rows()), y_abs(op->rows()), both(op->rows()), both_abs(op->rows());
  op->multiply(xv, y);
  op->absMultiply(xv, y_abs);
  op->multiplyWithAbs(xv, both, both_abs);
  return bp::make_tuple(y, y_abs, both, both_abs, static_cast<long>(op->productRoundingTerms()));
}

Constraint bilateral(const bp::object& rows) {
  return Constraint::bilateral(fromPython<int>(rows, "Constraint.bilateral: rows"));
}
Constraint planar(const bp::object& mu) { return Constraint::planarFriction(toDouble(mu, "Constraint.planar_friction: mu")); }
Constraint spatial(const bp::object& mu) { return Constraint::spatialFriction(toDouble(mu, "Constraint.spatial_friction: mu")); }

bp::list constraintsOf(const ContactProblem& p) {
  return pyList(p.constraints());
}

bp::list offsetsOf(const ContactProblem& p) {
  bp::list out;
  for (auto o : p.offsets()) out.append(static_cast<long>(o));
  return out;
}

Eigen::MatrixXd denseA(const ContactProblem& p) { return p.delassus().dense(); }
Eigen::VectorXd bOf(const ContactProblem& p) { return p.b(); }
void setB(ContactProblem& p, const bp::object& b) {
  p.setB(toVector(b, "ContactProblem.set_b: b", p.numRows()));
}

// Python's own float repr (the shortest that round-trips): eval(repr(c)) == c, box bounds included.
std::string floatRepr(double x) { return bp::extract<std::string>(bp::object(x).attr("__repr__")()); }
std::string constraintRepr(const Constraint& c) {
  switch (c.kind) {
    case ConstraintKind::kPlanarFriction:
    case ConstraintKind::kSpatialFriction:
      return std::string("stiction.Constraint.") + toString(c.kind) + "(mu=" + floatRepr(c.mu) + ")";
    case ConstraintKind::kBox:
      return "stiction.Constraint.box(lower=" + floatRepr(c.lower) + ", upper=" + floatRepr(c.upper) + ")";
    case ConstraintKind::kBilateral:
    case ConstraintKind::kUnilateral: break;
  }
  return "stiction.Constraint." + c.describe();
}
bool constraintEq(const Constraint& a, const bp::object& other) {
  bp::extract<const Constraint&> b(other);
  if (!b.check()) return false;
  return a.kind == b().kind && a.size == b().size && a.mu == b().mu && a.lower == b().lower && a.upper == b().upper;
}

}  // namespace

void exposeProblem() {
  bp::enum_<ConstraintKind>("ConstraintKind")
      .value("bilateral", ConstraintKind::kBilateral)
      .value("unilateral", ConstraintKind::kUnilateral)
      .value("planar_friction", ConstraintKind::kPlanarFriction)
      .value("spatial_friction", ConstraintKind::kSpatialFriction)
      .value("box", ConstraintKind::kBox);
  bp::enum_<ContactState>("ContactState")
      .value("open", ContactState::kOpen)
      .value("stick", ContactState::kStick)
      .value("slip", ContactState::kSlip)
      .value("closed", ContactState::kClosed);

  bp::class_<Constraint>("Constraint",
                         "One block of rows. Build with Constraint.bilateral(k), "
                         "Constraint.unilateral(), Constraint.planar_friction(mu), "
                         "Constraint.spatial_friction(mu), Constraint.box(lower, upper). Normal row last.",
                         bp::no_init)
      .def("bilateral", &bilateral, bp::arg("rows"), "k equality rows (C = R^k)")
      .staticmethod("bilateral")
      .def("unilateral", &Constraint::unilateral, "1 row, lambda_n >= 0")
      .staticmethod("unilateral")
      .def("planar_friction", &planar, bp::arg("mu"),
           "2 rows (t, n), |lambda_t| <= mu lambda_n")
      .staticmethod("planar_friction")
      .def("spatial_friction", &spatial, bp::arg("mu"),
           "3 rows (t1, t2, n), ||lambda_t|| <= mu lambda_n")
      .staticmethod("spatial_friction")
      .def("box", &Constraint::box, (bp::arg("lower"), bp::arg("upper")),
           "1 row, lower <= lambda <= upper (lower <= 0 <= upper): joint dry friction, actuator effort limits")
      .staticmethod("box")
      .def_readonly("kind", &Constraint::kind)
      .def_readonly("size", &Constraint::size)
      .def_readonly("mu", &Constraint::mu)
      .def_readonly("lower", &Constraint::lower)
      .def_readonly("upper", &Constraint::upper)
      .def("__repr__", &constraintRepr)
      .def("__eq__", &constraintEq);

  bp::class_<ContactProblem, std::shared_ptr<ContactProblem>>(
      "ContactProblem",
      "A lambda - b in -lim N_C^{U_eps}(lambda) (eq. 65): Delassus operator A, right-hand "
      "side b, and the list of constraint blocks. Raises ValueError on inconsistent input "
      "(sizes, NaN, mu < 0, an asymmetric or indefinite A) and TypeError on the wrong kind of argument. "
      "A may be a dense array or a scipy.sparse matrix (then held sparse: products and the NSGS / ADMM "
      "solvers cost O(entries)).",
      bp::no_init)
      .def("__init__",
           bp::make_constructor(&makeProblem, bp::default_call_policies(),
                                (bp::arg("A") = bp::object(), bp::arg("b") = bp::object(),
                                 bp::arg("constraints") = bp::object(), bp::arg("asymmetry_tolerance") = 1e-9)))
      .add_property("A", &denseA, "dense copy of the Delassus operator")
      .add_property("is_sparse", +[](const ContactProblem& p) { return p.delassus().sparse() != nullptr; },
                    "A is held sparse (built from a scipy.sparse matrix)")
      .add_property("nnz", +[](const ContactProblem& p) -> long {
                      const auto* s = p.delassus().sparse();
                      return s ? static_cast<long>(s->nonZeros()) : static_cast<long>(p.numRows() * p.numRows());
                    }, "stored entries of A")
      .add_property("b", &bOf)
      .add_property("constraints", &constraintsOf)
      .add_property("offsets", &offsetsOf, "first row of each block, then the row count")
      .add_property("num_rows", &ContactProblem::numRows)
      .add_property("num_blocks", &ContactProblem::numBlocks)
      .add_property("asymmetry", &ContactProblem::asymmetry, "max|A - A^T| / max|A|")
      .def("set_b", &setB, bp::arg("b"), "replace b (same size), keeping A");
  bp::def("_compensated_residual", &compensatedResidualOf,
          (bp::arg("A"), bp::arg("x"), bp::arg("b"), bp::arg("symmetric") = false),
          "(for tests) A x - b as the verdict's compensated stage computes it");
  bp::def("_operator_products", &operatorProductsOf, (bp::arg("A"), bp::arg("x"), bp::arg("symmetric") = false),
          "(for tests) (A x, |A||x|, A x and |A||x| from one pass, the rounding chain length) by the operator");
}

}  // namespace python
}  // namespace stiction
